"""``program = "simavr"``: the flashed images in simavr cores, in-process, as virtual modules'
programs (module_sim/simavr.py). Short runs of the pair scenario: against the host-built
firmware's frames, twice for determinism, per module from a scenario file, over two shards,
and the errors (a missing image, a library that does not load) as one line; thesis-6 in
profile thesis-2009 (the thesis planner, and the thesis's own way: a script of frames every
module executes) against the host-built firmware's frames. thesis-12 runs in the benchmark
(tests/benchmarks/test_simavr_bench.py)."""

from __future__ import annotations

import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import pytest

from bus.cheader import F_CPU, ubrr
from bus.timing import BITS_PER_BYTE, NS_PER_S, TICK_NS, Baud, byte_time_ns
from hexbench.cli import main
from recordings.reader import read_frames
from toolchain import needs_avr

ROOT = Path(__file__).resolve().parents[2]
pytestmark = needs_avr

#: The chip runs at its UBRR-exact baud rates (300.48, 4807.7), the host build at the nominal
#: ones: a 17-byte line ends about 1 ms earlier, plus the relays over UART0 (docs/firmware.md).
BAUD_DRIFT_NS = 3_000_000
NS_PER_CYCLE = NS_PER_S // F_CPU
#: Each wire's baud rate: the IR links at 300, UART0 and the debug UART1 at 4800.
LINK_BAUD = {"centre": Baud.IR, "side": Baud.IR, "uart0-down": Baud.UART0, "uart0-up": Baud.UART0,
             "debug": Baud.UART0}


def _run(tmp_path, name: str, *args: str, scenario: str = "pair", planner: str = "complete",
         code: int = 0) -> list:
    """The run's frames: (end, link, src, dst, raw, kind, channel, start), by time."""
    path = tmp_path / f"{name}.mcap"
    assert main(["run", scenario, "--planner", planner, "--clock", "virtual", "--isolated",
                 "--record", str(path), *args]) == code
    return sorted((e.sim_time_ns, e.link, e.src, e.dst, e.raw, e.kind, e.channel, e.first_byte_ns)
                  for e in read_frames(path))


def _power_ups(host: list) -> dict[str, int]:
    """Each module's power-up instant: the host build sends its banner then (the fleet's
    seeded phase, the same in every run of the scenario)."""
    out: dict[str, int] = {}
    for f in host:
        if f[1] == "centre":
            out.setdefault(f[2].split(".")[0], f[7])
    return out


def _assert_the_chip_sent(frames: list, power_up: dict[str, int]) -> int:
    """What only the images on the chip do, for every frame a board sent; how many frames.

    * UBRR-exact bytes: each byte takes 10 x 16 x (UBRR + 1) cycles (33.28 ms on IR, 2.08 ms on
      UART0 and UART1), so n bytes last at least n of them and, back to back within a few
      cycles, less than n nominal bytes (the host build's 33.33 ms and 2.083 ms exactly).
    * The 1 MHz cycle grid: every start and end a whole number of cycles after power-up.
    * The tick grid: Timer0 starts in .init3 and the code between a tick and the write to UDR
      takes cycles, so no frame starts on the host build's grid (power-up + k ticks), where
      every frame the host build starts after a wait does."""
    sent = 0
    for end, link, src, _dst, raw, _kind, _channel, start in frames:
        if src == "pc":
            continue
        baud, n = LINK_BAUD[link], len(raw)
        chip_byte = BITS_PER_BYTE * 16 * (ubrr(baud) + 1) * NS_PER_CYCLE
        assert n * chip_byte <= end - start < n * byte_time_ns(baud), (link, src, raw, start, end)
        since = start - power_up[src.split(".")[0]]
        assert since % NS_PER_CYCLE == 0 and (end - start) % NS_PER_CYCLE == 0, (link, src, raw, start)
        assert since % TICK_NS != 0, (link, src, raw, start)
        sent += 1
    return sent


@pytest.fixture(scope="module")
def simavr_pair(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("simavr"), "simavr", "--program", "simavr")


def _wires(frames) -> dict:
    out = defaultdict(list)
    for f in frames:
        out[(f[1], f[2], f[3])].append(f[4])
    return out


def test_the_centre_channel_carries_the_host_firmwares_bytes(tmp_path, simavr_pair, capsys):
    """The same frames as --program firmware on every wire, in order; on the centre channel
    each module's answer comes within a tick (plus the baud drift) of where the host build
    puts it after the PC's frame before it. The planner answers each frame as it arrives, so
    absolute times carry the differences of the exchanges before. And every one of them was
    sent by the chip (:func:`_assert_the_chip_sent`), which the host build fails."""
    host = _run(tmp_path, "firmware", "--program", "firmware")
    assert "complete: goal reached" in capsys.readouterr().out
    assert _wires(simavr_pair) == _wires(host)
    centre = [[f for f in run if f[1] in ("centre", "pc")] for run in (host, simavr_pair)]
    assert _within_a_tick(*centre)[1] >= 10
    power_up = _power_ups(host)
    assert _assert_the_chip_sent(simavr_pair, power_up) == sum(f[2] != "pc" for f in host)
    with pytest.raises(AssertionError):  # the check tells the host build from the chip
        _assert_the_chip_sent(host, power_up)


def _within_a_tick(host: list, sim: list) -> tuple[int, int]:
    """``host`` and ``sim``: frames of the PC and of modules on the centre channel. The same
    senders and bytes in the same order, and each module frame within a tick (plus the baud
    drift) of the host build's, measured from the PC frame before it (from power-up before
    the first). Returns how many module frames were compared, and how many of them came
    after a PC frame (answers)."""
    assert [(f[2], f[4]) for f in host] == [(f[2], f[4]) for f in sim]
    last_pc, compared, answers = None, 0, 0
    for i, (a, b) in enumerate(zip(host, sim)):
        if a[1] == "pc":
            last_pc = i
            continue
        t0 = (host[last_pc][0], sim[last_pc][0]) if last_pc is not None else (0, 0)
        assert abs((b[0] - t0[1]) - (a[0] - t0[0])) < TICK_NS + BAUD_DRIFT_NS, (i, a, b)
        compared += 1
        answers += last_pc is not None
    return compared, answers


def test_two_runs_give_the_same_frames_at_the_same_times(tmp_path, simavr_pair):
    assert _run(tmp_path, "again", "--program", "simavr") == simavr_pair


def test_a_scenario_module_runs_simavr_beside_the_model(tmp_path, capsys):
    """``program = "simavr"`` on one module of a scenario file: it runs beside a Python one."""
    text = (ROOT / "bus/scenarios/pair.toml").read_text()
    scenario = tmp_path / "mixed.toml"
    scenario.write_text(text.replace("cell = [1, 0]\nid = 2", 'cell = [1, 0]\nid = 2\nprogram = "simavr"'))
    frames = _run(tmp_path, "mixed", scenario=str(scenario))
    assert "complete: goal reached" in capsys.readouterr().out
    assert any(f[2] == "m2.comm" for f in frames)


def test_two_shards_give_the_one_process_frames(tmp_path, simavr_pair):
    """Simavr modules in shard processes, on the lockstep clock: the one-process frames (the
    optical switches reach the pins at a fixed delay, whatever the lookahead)."""
    out = tmp_path / "sharded.mcap"
    r = subprocess.run([sys.executable, "-m", "hexbench", "run", "pair", "--planner", "complete",
                        "--clock", "virtual", "--program", "simavr", "--shards", "2",
                        "--fleet", f"simavr-shards-{id(tmp_path)}", "--record", str(out)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "complete: goal reached" in r.stdout
    got = sorted((e.sim_time_ns, e.link, e.src, e.dst, e.raw, e.kind, e.channel, e.first_byte_ns)
                 for e in read_frames(out))
    assert got == simavr_pair


def test_a_missing_image_is_one_line(monkeypatch, capsys):
    import module_sim.simavr as simavr

    monkeypatch.setattr(simavr, "build_path", lambda kind, board, profile: Path(f"/nonexistent/{board}.elf"))
    monkeypatch.setattr(simavr, "ensure_built", lambda: None)
    assert main(["run", "pair", "--planner", "complete", "--clock", "virtual", "--isolated",
                 "--program", "simavr"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["hexbench run: error: m1 (simavr): cannot read the comm image /nonexistent/comm.elf: "
                   "No such file or directory"]


def test_a_library_that_does_not_load_is_one_line(monkeypatch, tmp_path, capsys):
    """What a missing libsimavr looks like to ctypes: the library does not load."""
    import module_sim.simavr as simavr

    (tmp_path / simavr.LIB_NAME).write_bytes(b"not a shared object")
    monkeypatch.setattr(simavr, "BUILD_DIR", tmp_path)
    monkeypatch.setattr(simavr, "_lib", None)
    assert main(["run", "pair", "--planner", "complete", "--clock", "virtual", "--isolated",
                 "--program", "simavr"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"hexbench run: error: cannot load {tmp_path}/"), err
    assert "install simavr" in err[0]


#: thesis-2009 has no addressing: every module executes (and answers) every frame. LEDs, one
#: thesis localization step (sides 2 and 3, side IR between the modules), the LED circle (a
#: byte out of every side).
THESIS_2009_SCRIPT = """\
send LOn
wait 2
send LOff
wait 2
send Localize
wait 12
send LCircle 1 5
wait 6
"""


@pytest.mark.parametrize("planner", ["thesis-serial", "script"])
def test_thesis_6_in_thesis_2009_gives_the_host_firmwares_frames(tmp_path, capsys, planner):
    """Issue 41: thesis-6 with every module simavr and profile thesis-2009, as the project
    runs it: the thesis planner (the bring-up, then its refusal: no addressing) and a
    script:<file> planner (the thesis's own way). Against --program firmware: every wire the
    same frames in the same order; each module's frames on the centre channel, among the
    PC's, in the same order, each within a tick (plus the baud drift) of the host build's
    after the PC frame before it. Named difference (docs/firmware.md): modules answering the
    same broadcast answer at the same nanosecond in the host build and on their own tick grids
    in simavr, so their answers interleave in another order across modules."""
    if planner == "script":
        (tmp_path / "t.txt").write_text(THESIS_2009_SCRIPT)
        planner, code, said = f"script:{tmp_path / 't.txt'}", 0, "script finished"
    else:
        code, said = 1, "thesis-2009 modules have no addressing"
    args = ("--profile", "thesis-2009")
    runs = {p: _run(tmp_path, p, *args, "--program", p, scenario="thesis-6", planner=planner, code=code)
            for p in ("firmware", "simavr")}
    out = capsys.readouterr().out
    assert out.count(said) >= 2, out[-2000:]
    host, sim = runs["firmware"], runs["simavr"]
    assert _wires(sim) == _wires(host)
    modules = {f[2] for f in host if f[1] == "centre"}
    assert len(modules) == 6
    answers = 0
    for m in sorted(modules):
        a, b = ([f for f in run if f[1] == "pc" or (f[1], f[2]) == ("centre", m)]
                for run in (host, sim))
        compared, answered = _within_a_tick(a, b)
        assert compared >= 1  # its boot banner at least
        answers += answered
    if code == 0:  # the script's four frames, every module answering (the thesis planner
        assert answers >= 24  # refuses before the PC sends a frame: only the boot's compared)
    _assert_the_chip_sent(sim, _power_ups(host))

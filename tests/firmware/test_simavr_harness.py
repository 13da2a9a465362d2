"""hexbot-simavr: the ATmega162 core for libsimavr and the two-board harness, proven by
firmware/simavr/selftest.c running on both boards, in real time over the IR pseudo-terminal
and in --fast mode against the event log."""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest

from bus import pins
from toolchain import missing, module

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "firmware" / "simavr"
BUILD = ROOT / "firmware" / "build"
HARNESS = BUILD / "hexbot-simavr"
SELFTEST = BUILD / "simavr-selftest.elf"

MS = 1_000_000  # ns
IR_FRAME = 33_333_000  # ns: a 10-bit frame from the PC at 300 Bd (rounded to whole cycles)
TX_FRAME = 33_280_000  # ns: 10 bits at UBRR 207, 1e6 / (16 * 208) = 300.48 Bd
TICK = 9_984_000  # ns: Timer0, prescaler 64, reload 0x64


def _why_not() -> str | None:
    for tool in ("make", "cc", "avr-gcc"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed"
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        return "the simavr headers are not installed (libsimavr-dev)"
    if not Path("/usr/lib/avr/include/avr/iom162.h").exists():
        return "avr-libc is not installed"
    return None


@pytest.fixture(scope="module")
def elf() -> Path:
    why = _why_not()
    if why:
        missing(why)
    r = subprocess.run(["make", "-C", str(SRC), "selftest"], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    return SELFTEST


def _harness(elf: Path, *args: object, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([str(HARNESS), "--comm", str(elf), "--control", str(elf),
                           *map(str, args)], capture_output=True, text=True, timeout=timeout)


def _readline(proc: subprocess.Popen, timeout: float) -> str:
    """One line of the harness's stdout, or fail after timeout seconds."""
    deadline = time.monotonic() + timeout
    buf = b""
    while not buf.endswith(b"\n"):
        left = deadline - time.monotonic()
        assert left > 0, f"no ready line within {timeout} s: {buf!r}"
        if select.select([proc.stdout], [], [], left)[0]:
            chunk = os.read(proc.stdout.fileno(), 1)
            assert chunk, f"harness exited: {proc.stderr.read()!r}"
            buf += chunk
    return buf.decode()


def _events(log: Path) -> list[tuple[int, str, tuple[str, ...]]]:
    out = []
    for line in log.read_text().splitlines():
        t, kind, *rest = line.split()
        out.append((int(t), kind, tuple(rest)))
    return out


def test_builds_without_warnings(tmp_path) -> None:
    why = _why_not()
    if why:
        missing(why)
    r = subprocess.run(["make", "-B", "-C", str(SRC), f"SIMAVR_OUT={tmp_path}", "selftest"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "warning:" not in r.stderr, r.stderr
    assert (tmp_path / "hexbot-simavr").exists() and (tmp_path / "simavr-selftest.elf").exists()


def test_real_time_echo_over_the_ir_and_debug_ptys(elf, tmp_path) -> None:
    serial = module("serial")
    ir_link, debug_link = tmp_path / "ir", tmp_path / "debug"
    debug_link.symlink_to("/nonexistent")  # a stale link from a run that died is replaced
    proc = subprocess.Popen([str(HARNESS), "--comm", str(elf), "--control", str(elf),
                             "--ir-link", str(ir_link), "--debug-link", str(debug_link)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        ready = _readline(proc, 10)
        m = re.fullmatch(r"hexbot-simavr: ir=(/dev/pts/\d+) debug=(/dev/pts/\d+)\n", ready)
        assert m, ready
        assert os.readlink(ir_link) == m[1] and os.readlink(debug_link) == m[2]
        with serial.Serial(str(ir_link), 300, timeout=2) as ir, \
                serial.Serial(str(debug_link), 4800, timeout=2) as debug:
            # the module answers once booted (well under a millisecond): wait for it
            probes, deadline = 0, time.monotonic() + 10
            while True:
                ir.write(b"0")
                probes += 1
                ir.timeout = 0.5
                if ir.read(1) == b"1":
                    break
                assert time.monotonic() < deadline, "no echo from the comm board"
            assert debug.read(probes).endswith(b"0")  # forwarded comm -> control -> debug
            ir.timeout = 2
            start = time.monotonic()
            ir.write(b"ABC")
            assert ir.read(3) == b"BCD"  # +1 echoes from the comm board's USART1
            elapsed = time.monotonic() - start
            assert debug.read(3) == b"ABC"  # and the same bytes over USART0 to the control board
        # three bytes in and the last one back: four 10-bit frames at 300 Bd, in real time
        assert 4 * IR_FRAME / 1e9 <= elapsed < 0.6
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert not os.path.lexists(ir_link) and not os.path.lexists(debug_link)


def test_real_time_pacing_and_writes_nobody_reads(elf, tmp_path) -> None:
    """Simulated time follows the wall clock; bytes for a pty nobody has open are dropped
    without blocking; SIGTERM ends the run cleanly."""
    script = tmp_path / "ir.txt"
    script.write_text("100000000 41\n")  # the echo and the forwarded byte find no reader
    link = tmp_path / "ir"
    proc = subprocess.Popen([str(HARNESS), "--comm", str(elf), "--control", str(elf),
                             "--ir-link", str(link), "--ir-script", str(script),
                             "--seconds", "1.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _readline(proc, 10)
    start = time.monotonic()
    _, err = proc.communicate(timeout=10)
    elapsed = time.monotonic() - start
    assert proc.returncode == 0, err
    assert 1.45 <= elapsed < 2.0, elapsed
    assert "stopped at 1.5" in err.decode() and "pty bytes dropped 2" in err.decode()
    assert not os.path.lexists(link)

    proc = subprocess.Popen([str(HARNESS), "--comm", str(elf), "--control", str(elf),
                             "--ir-link", str(link)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _readline(proc, 10)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert not os.path.lexists(link)


T_A, T_BURST, T_T1, T_T2, T_FRAME = 100 * MS, 300 * MS, 600 * MS, 1600 * MS, 1700 * MS
T_SIDE, T_DROP, T_A2, T_DIP, T_SW = 2200 * MS, 2260 * MS, 2500 * MS, 2700 * MS, 2800 * MS
T_SWA, T_SWD, T_CTC, T_END = 2850 * MS, 2900 * MS, 3000 * MS, 4500 * MS
FRAME = bytes.fromhex("2a15010000000000000023")
DIP, SWITCHES = 0xA5, 0x2B  # sides 1, 2, 4, 6 have a neighbour


@pytest.fixture(scope="module")
def fast_log(elf, tmp_path_factory) -> list[tuple[int, str, tuple[str, ...]]]:
    tmp = tmp_path_factory.mktemp("fast")
    script = tmp / "ir.txt"
    script.write_text(
        "# <sim_time_ns> <hex bytes>\n"
        f"{T_A} 41\n{T_BURST} 62\n{T_T1} 74\n{T_T2} 74\n{T_FRAME} {FRAME.hex()}\n"
        f"{T_SIDE} 73\n{T_DROP} 71\n{T_A2} 41\n{T_DIP} 64\n{T_SW} 77\n{T_SWA} 61\n"
        f"{T_SWD} 70\n{T_CTC} 63\n")
    logs = []
    for run in (1, 2):
        log = tmp / f"log{run}.txt"
        r = _harness(elf, "--fast", "--seconds", T_END / 1e9, "--ir-script", script, "--log", log,
                     "--dip", hex(DIP), "--switches", hex(SWITCHES))
        assert r.returncode == 0, r.stderr
        logs.append(log.read_text())
    assert logs[0] == logs[1]  # deterministic
    return _events(tmp / "log1.txt")


def _after(events, t0, kind, *, board=None):
    return [(t, a) for t, k, a in events if k == kind and t >= t0 and (board is None or a[0] == board)]


def test_fast_log_is_ordered_and_shows_the_ports(fast_log) -> None:
    times = [t for t, _, _ in fast_log]
    assert times == sorted(times)
    ports = [(k, a) for _, k, a in fast_log if k == "port"]
    for board in ("comm", "control"):
        assert ("port", (board, "E", "05")) in ports
        assert ("port", (board, "A", "02")) in ports  # the multiplexer on the centre


def test_fast_echo_times(fast_log) -> None:
    # 'A' arrives over one PC frame; RXC at its end, the +1 echo right after
    t, a = _after(fast_log, T_A, "ir")[0]
    assert a == ("42",) and 0 <= t - (T_A + IR_FRAME) < 300_000
    t_dbg, a = _after(fast_log, T_A, "debug")[0]  # forwarded over USART0 at 4800 Bd
    assert a == ("41",) and t < t_dbg < t + 5 * MS

    # an 11-byte frame: the PC's bytes back to back, each echoed at the end of its own frame
    echoes = _after(fast_log, T_FRAME, "ir")[: len(FRAME)]
    assert [int(a[0], 16) for _, a in echoes] == [(b + 1) & 0xFF for b in FRAME]
    for i, (t, _) in enumerate(echoes):
        assert 0 <= t - (T_FRAME + (i + 1) * IR_FRAME) < 300_000


def test_fast_transmit_is_ten_bits_at_the_ubrr_baud(fast_log) -> None:
    burst = _after(fast_log, T_BURST, "ir")[:3]
    assert [a[0] for _, a in burst] == ["78", "79", "7a"]
    for (t0, _), (t1, _) in zip(burst, burst[1:]):
        # back to back: one frame of 10 bits at 300.48 Bd (not 11 bits, not 300 Bd) plus
        # the few cycles the program takes to see UDRE and write UDR1
        assert TX_FRAME <= t1 - t0 < TX_FRAME + 20_000


def _tick_toggles(fast_log, start, end):
    """PD7 toggles of the comm board (one per Timer0 interrupt) in [start, end)."""
    return [t for t, k, a in fast_log
            if k == "port" and a[:2] == ("comm", "D") and start <= t < end]


def test_fast_tick_is_9_984_ms(fast_log) -> None:
    toggles = _tick_toggles(fast_log, 0, T_CTC)
    gaps = [b - a for a, b in zip(toggles, toggles[1:])]
    assert len(gaps) > 250
    assert sorted(gaps)[len(gaps) // 2] == TICK
    assert all(abs(g - TICK) < 100_000 for g in gaps)  # ISR latency jitter only
    assert abs((toggles[-1] - toggles[0]) / len(gaps) - TICK) < 1_000
    # two 't' one second apart: 1 s / 9.984 ms = 100.16 ticks
    (_, r1), (_, r2) = _after(fast_log, T_T1, "ir")[0], _after(fast_log, T_T2, "ir")[0]
    assert (int(r2[0], 16) - int(r1[0], 16)) % 256 in (100, 101)


def test_fast_ctc_tick_is_9_984_ms(fast_log) -> None:
    """'c' moves Timer0 to CTC mode (OCR0 = 155, compare-match interrupt, no reload): the
    counter clears itself after 156 counts, so the tick stays on the 64-cycle grid."""
    t_switch = _after(fast_log, T_CTC, "ir")[0][0]  # the answer: TCNT0 just after the switch
    toggles = _tick_toggles(fast_log, t_switch + 2 * TICK, T_END)  # the first round is partial
    gaps = [b - a for a, b in zip(toggles, toggles[1:])]
    assert len(gaps) > 100
    assert all(abs(g - TICK) < 20_000 for g in gaps), sorted(set(gaps))
    # no drift: every tick within the ISR's latency jitter of its slot on the grid
    assert all(abs(t - toggles[0] - k * TICK) < 20_000 for k, t in enumerate(toggles))


def test_fast_side_channel_drops_bytes_both_ways(fast_log) -> None:
    t_side = T_SIDE + IR_FRAME  # 's' received: PORTA -> PA2 (channel 1), 'S' sent there
    side = [(t, a) for t, a in _after(fast_log, T_SIDE, "port", board="comm") if a[1] == "A"]
    assert side[0][1] == ("comm", "A", "04") and side[1][1] == ("comm", "A", "02")
    assert t_side < side[0][0] < t_side + MS
    (t, a), = _after(fast_log, T_SIDE, "irside")[:1]
    assert a == ("53", "1") and side[0][0] <= t < t_side + MS
    # 'q' reaches the module while a side is selected: dropped at its start bit, no echo
    assert (T_DROP, "irdrop", ("71", "1")) in fast_log
    ir_after = _after(fast_log, T_SIDE, "ir")
    assert ("72",) not in [a for t, a in ir_after if t < T_A2]
    # back on the centre ten ticks later with 'C'; then echoes again
    (t_c, a_c), (t_b, a_b) = ir_after[:2]
    assert a_c == ("43",) and side[1][0] <= t_c
    assert 9 * TICK <= t_c - side[0][0] <= 10 * TICK + MS  # ten tick increments
    assert a_b == ("42",) and 0 <= t_b - (T_A2 + IR_FRAME) < 300_000


def _byte(events, t0, kind):
    return int(_after(events, t0, kind)[0][1][0], 16)


def test_fast_dip_and_switch_inputs(fast_log) -> None:
    """Both switch kinds are active low (bus.pins): a closed switch pulls its pin low, an
    open one reads high (the pull-up the image sets)."""
    assert pins.DIP_ACTIVE_LOW and pins.OPTICAL_SWITCH_ACTIVE_LOW
    # 'd': the comm board has no DIP switches; the control board's PINC reads --dip's complement
    assert _byte(fast_log, T_DIP, "ir") == 0x00
    assert _byte(fast_log, T_DIP, "debug") == pins.dip_levels(DIP) == 0x5A
    # --switches 0x2B = sides 1, 2, 4, 6: PB0, PB1 and PA3, PD2 low; side 3's PB4 and side
    # 5's PA4 high; the control board has no optical switches
    levels = pins.switch_levels([bool(SWITCHES >> k & 1) for k in range(6)])
    assert levels == {"B": 0x10, "A": 0x10, "D": 0x00}
    assert _byte(fast_log, T_SW, "ir") == levels["B"]  # 'w': PINB, no other pin driven
    assert _byte(fast_log, T_SW, "debug") == 0x00
    masks = pins.port_masks(list(pins.OPTICAL_SWITCH.values()))
    assert _byte(fast_log, T_SWA, "ir") & masks["A"] == levels["A"]  # 'a': PINA
    assert _byte(fast_log, T_SWD, "ir") & masks["D"] == levels["D"]  # 'p': PIND


def _one_line(err: str) -> str:
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hexbot-simavr: "), err
    return lines[0]


def test_errors_are_one_line_and_exit_2(elf, tmp_path) -> None:
    text = tmp_path / "text.elf"
    text.write_text("not an ELF at all, but long enough to have a header\n")
    cases = [
        ["--comm", tmp_path / "missing.elf", "--control", elf],
        ["--comm", text, "--control", elf],
        ["--comm", elf, "--control", elf, "--bogus"],
        ["--comm", elf, "--control", elf, "--dip", "256"],
        ["--comm", elf, "--control", elf, "--fast"],
        ["--comm", elf, "--control", elf, "--board-record", "comm=bogus"],
        ["--comm", elf, "--control", elf, "--board-record", "side=comm"],
        ["--comm", elf, "--control", elf, "--trace", "ddr,clock", "--log", "-"],
        ["--comm", elf, "--control", elf, "--trace", "tick"],
        ["--comm", elf],
    ]
    for args in cases:
        r = subprocess.run([str(HARNESS), *map(str, args)], capture_output=True, text=True,
                           timeout=30)
        assert r.returncode == 2, (args, r.stderr)
        _one_line(r.stderr)
        assert "Traceback" not in r.stderr and "core dumped" not in r.stderr
    assert "missing.elf" in subprocess.run(
        [str(HARNESS), "--comm", str(tmp_path / "missing.elf"), "--control", str(elf)],
        capture_output=True, text=True).stderr


def test_a_crash_names_the_board_and_pc(elf, tmp_path) -> None:
    script = tmp_path / "ir.txt"
    script.write_text(f"{T_A} 58\n")  # 'X': the comm board writes outside its RAM
    r = _harness(elf, "--fast", "--seconds", 1, "--ir-script", script)
    assert r.returncode == 1
    assert re.fullmatch(r"hexbot-simavr: comm board crashed at PC 0x[0-9a-f]{4} .*",
                        _one_line(r.stderr))

"""The board layer on the ATmega162 (firmware/avr/board_avr.c), the flashed images run in
simavr (--fast, cycle-exact): an image drives no pin unless the EEPROM's board-kind record
names its board, the 9.984 ms tick keeps its grid while the control board reports its
actuators, and no interrupt waits for a division."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from bus.codec import ACT_TAG, EOL, GUARD_TEXTS, PREAMBLE, encode_command
from bus.pins import port_masks
from toolchain import needs_avr

pytestmark = needs_avr

TICK_CYCLES = 9984  # Timer0: 156 counts of 64 cycles at 1 MHz
COUNT_CYCLES = 64  # one Timer0 count
NS = 1000  # per cycle


@pytest.fixture(scope="module")
def harness() -> Path:
    from hil.firmware import HARNESS, ensure_built

    ensure_built()
    return HARNESS


def _run(harness: Path, tmp: Path, comm: Path, control: Path, seconds: float, *args: str,
         script: list[tuple[int, bytes]] = ()) -> list[tuple[int, str, tuple[str, ...]]]:
    """(time_ns, kind, fields) of every log line: ports, DDRs, Timer0 interrupts, bytes."""
    log = tmp / "log.txt"
    cmd = [str(harness), "--comm", str(comm), "--control", str(control), "--fast",
           "--seconds", f"{seconds:g}", "--log", str(log), "--trace", "ddr,tick", *args]
    if script:
        (tmp / "ir.txt").write_text("".join(f"{t} {data.hex()}\n" for t, data in script))
        cmd += ["--ir-script", str(tmp / "ir.txt")]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = []
    for line in log.read_text().splitlines():
        t, kind, *rest = line.split()
        out.append((int(t), kind, tuple(rest)))
    return out


def _uart1(events, board: str) -> list[tuple[int, int]]:
    """(time_ns, byte) a board's UART1 sent: the control board's debug UART, or the comm
    board's IR whichever channel its (undriven) multiplexer inputs select."""
    kinds = ("debug",) if board == "control" else ("ir", "irside")
    return [(t, int(a[0], 16)) for t, k, a in events if k in kinds]


def _images(profile: str) -> tuple[Path, Path]:
    from hil.firmware import images

    return images(profile)


# --- each image knows its board ----------------------------------------------------------

GUARD_CASES = {
    # slot (the board the record names) -> (image built for, what it prints)
    "swapped": {"comm": ("control", "comm"), "control": ("comm", "control")},
    "no-record": {"comm": ("comm", "none"), "control": ("control", "none")},
}
#: a byte of UART1 in ns: the control board's debug UART (UBRR 12), the comm board's IR (UBRR 207)
BYTE_NS = {"control": 10 * 16 * 13 * NS, "comm": 10 * 16 * 208 * NS}


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
@pytest.mark.parametrize("case", sorted(GUARD_CASES))
def test_an_image_on_a_board_not_its_own_drives_no_pin(harness, tmp_path, profile, case):
    """The comm image in the control board's slot (its EEPROM says control) and the control
    image in the comm board's (says comm); or both boards without a record. For 10 s no DDR
    or PORT bit is ever set on either board; each says why on its UART1, about once a
    second, at the baud of the board the record names (its own without one)."""
    comm_elf, control_elf = _images(profile)
    elf = {"comm": comm_elf, "control": control_elf}
    slots = GUARD_CASES[case]
    args = [] if case == "swapped" else ["--board-record", "comm=none",
                                        "--board-record", "control=none"]
    events = _run(harness, tmp_path, elf[slots["comm"][0]], elf[slots["control"][0]], 10, *args)

    driven = [(t, k, a) for t, k, a in events if k in ("ddr", "port")]
    assert driven == [], f"pins set on a board not the image's own: {driven[:5]}"
    assert not any(k == "tick" for _, k, _ in events)  # no program, no tick interrupt
    for slot, (image, found) in slots.items():
        line = PREAMBLE + GUARD_TEXTS[(image, found)] + EOL
        sent = _uart1(events, slot)
        data = bytes(b for _, b in sent)
        assert data.startswith(line) and data == line * (len(data) // len(line)) + \
            line[:len(data) % len(line)], data[:120]
        # the baud: the record's board (the image's own board without one)
        baud_of = slot if found != "none" else image
        assert sent[1][0] - sent[0][0] == BYTE_NS[baud_of]
        # a line, a second's pause (from the last byte in UDR, two bytes before the line
        # ends), the next line
        starts = [sent[i][0] for i in range(0, len(sent), len(line))]
        quiet = {b - a - len(line) * BYTE_NS[baud_of] for a, b in zip(starts, starts[1:])}
        assert len(starts) >= 3 and all(0.9e9 < q < 1.1e9 for q in quiet), (slot, quiet)


def _header_masks(name: str) -> dict[str, int]:
    """{port: mask} of hexbot_gen.h's NAME_A..NAME_E (the outputs and pull-ups from bus/)."""
    from bus.cheader import FIRMWARE_DIR

    text = (FIRMWARE_DIR / "include" / "hexbot_gen.h").read_text()
    return {p: int(v, 16) for p, v in re.findall(rf"#define {name}_([A-E]) (0x[0-9a-f]+)", text)}


def test_an_image_on_its_own_board_sets_its_pins(harness, tmp_path):
    """The record each slot gets by default names its own board: the images run, with the
    outputs and pull-ups of hexbot_gen.h (the other side of the test above)."""
    events = _run(harness, tmp_path, *_images("v2"), 2)
    for board in ("control", "comm"):
        ddr = {a[1]: int(a[2], 16) for t, k, a in events if k == "ddr" and a[0] == board}
        outputs = _header_masks(f"{board.upper()}_OUTPUTS")
        assert ddr == {p: m for p, m in outputs.items() if m}, board
        first_port: dict[str, int] = {}
        for _, k, a in events:
            if k == "port" and a[0] == board:
                first_port.setdefault(a[1], int(a[2], 16))
        for p, m in _header_masks(f"{board.upper()}_PULLUPS").items():
            if m:
                assert first_port[p] & m == m, (board, p)  # the pull-ups, set at board_init
    banner = bytes(b for _, b in _uart1(events, "control"))
    assert b"CTR. BOARD READY" in banner


# --- the tick under load ------------------------------------------------------------------

#: JTest(2 rounds, 1 tick): 24 actuator steps one tick apart, an ACT report each (the debug
#: UART at 4800 Bd cannot keep up: its queue stays busy). One every 110 ticks plus 0.2 ms,
#: so the report a command queues at once (its first step) meets the tick at a phase 0.2 ms
#: later each time: 50 commands sweep the whole 9.984 ms.
LOAD_START_NS, LOAD_COMMANDS = 11_000_000_000, 50
LOAD_GAP_NS = (110 * TICK_CYCLES + 200) * NS


def _tick_load() -> list[tuple[int, bytes]]:
    return [(LOAD_START_NS + i * LOAD_GAP_NS, encode_command("JTest", 2, 1))
            for i in range(LOAD_COMMANDS)]


def test_the_tick_keeps_its_grid_while_the_control_board_reports(harness, tmp_path):
    """Timer0 in CTC mode clears itself: with ACT reports going out all the time, every tick
    of the control board (its interrupt's entry) comes within one Timer0 count (64 cycles)
    of 9 984 cycles after the one before, and of its place on the grid. The reload in the
    overflow interrupt (TCNT0 = 0x64) lost a count whenever that interrupt came 64 cycles
    late, behind a queue update with interrupts off or a UDRE handler: 1 100 cycles
    behind the grid after 5 000 ticks of this load."""
    seconds = (LOAD_START_NS + LOAD_COMMANDS * LOAD_GAP_NS) / 1e9 + 1
    events = _run(harness, tmp_path, *_images("v2"), seconds, "--dip", "1", script=_tick_load())

    debug = bytes(b for _, b in _uart1(events, "control"))
    assert debug.count(ACT_TAG) > 15 * LOAD_COMMANDS  # the load: reports all along
    centre = bytes(int(a[0], 16) for _, k, a in events if k == "ir")
    assert centre.count(b"ACK") == LOAD_COMMANDS  # every command ran

    ticks = [t // NS for t, k, a in events if k == "tick" and a[0] == "control"
             and t >= LOAD_START_NS]
    assert len(ticks) >= 1000
    periods = [b - a for a, b in zip(ticks, ticks[1:])]
    off_grid = [t - ticks[0] - k * TICK_CYCLES for k, t in enumerate(ticks)]
    worst_period = max(periods, key=lambda p: abs(p - TICK_CYCLES))
    assert abs(worst_period - TICK_CYCLES) < COUNT_CYCLES, (min(periods), max(periods))
    assert max(off_grid) - min(off_grid) < COUNT_CYCLES, (min(off_grid), max(off_grid))


# --- no division with interrupts off ------------------------------------------------------

def _functions(elf: Path) -> dict[str, list[str]]:
    """Each function's instructions (mnemonic and operands) from avr-objdump."""
    out: dict[str, list[str]] = {}
    name = None
    for line in subprocess.run(["avr-objdump", "-d", str(elf)], capture_output=True,
                               text=True, check=True).stdout.splitlines():
        m = re.match(r"^[0-9a-f]+ <(.+)>:$", line)
        if m:
            name = m[1]
            out[name] = []
        elif name and (parts := line.split("\t")) and len(parts) >= 3:
            out[name].append(" ".join(parts[2:]).strip())
    return out


def _interrupts_off(name: str, body: list[str]) -> list[list[str]]:
    """The stretches of a function that run with interrupts off: from a cli to the sei or
    SREG restore (out 0x3f) after it; in an interrupt handler (entered with interrupts off)
    also from its entry to a sei, and from a cli to its reti."""
    handler = name.startswith("__vector_")
    out, start = [], 0 if handler else None
    for i, ins in enumerate(body):
        op = ins.split()[0]
        if op == "cli":
            start = i
        elif start is not None and (op == "sei" or op == "reti" or
                                    (not handler and re.match(r"out\s+0x3f,", ins))):
            out.append(body[start:i + 1])
            start = None
    return out


@pytest.mark.parametrize("image", ["comm-v2", "control-v2", "comm-thesis", "control-thesis"])
def test_interrupts_are_off_for_a_few_instructions_and_call_nothing(image):
    """Nothing is called with interrupts off (no __divmodhi4 in a queue update, as there
    was); outside the interrupt handlers they are off for a few instructions at a time."""
    from bus.cheader import build_path, ensure_built

    ensure_built()
    board, profile = image.split("-")
    funcs = _functions(build_path("elf", board, "v2" if profile == "v2" else "thesis-2009"))
    assert "__vector_16" in funcs and "__vector_17" not in funcs  # TIMER0_COMP, not _OVF
    program = 0
    for name, body in funcs.items():
        if name in ("_exit", "__stop_program"):  # the runtime's end: cli, then a loop
            continue
        for stretch in _interrupts_off(name, body):
            calls = [ins for ins in stretch if ins.split()[0] in ("call", "rcall", "icall")]
            assert not calls, (name, stretch)
            if not name.startswith("__vector_"):
                program += 1
                assert len(stretch) <= 6, (name, stretch)
    assert program  # board_ticks reads the tick counter with interrupts off


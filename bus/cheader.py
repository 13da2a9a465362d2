"""The C firmware's constants, written from this package (one truth for Python and C),
and where its builds are.

``python -m bus.cheader`` prints ``firmware/include/hexbot_gen.h``: the function table
(Table 3-7 and our v2 codes), the pin maps (Tables 3-3..3-5), the timing constants, the
wire texts of the codec, the rotation programs and the two lattice tables the comm board
needs (Table 4-1 offsets, Table 4-3 goals). ``--check FILE`` exits 1 when FILE differs,
which is how a test keeps the committed header from drifting.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

from . import chip, codec, pins, rotations, timing
from .functions import ACK_TIMEOUT, ACK_UNKNOWN, ARG_UNUSED, BY_NAME, FUNCTIONS, Board, WalterFlag, WalterOp
from .lattice import NEIGHBOUR_OFFSET, Cell, Direction, Joint, Side, move_rule

from .errors import HexbenchError

#: The firmware tree (next to the packages in a checkout, or $HEXBENCH_FIRMWARE) and what
#: ``make -C firmware`` builds there: the images, the simavr harness, the host libraries.
FIRMWARE_DIR = Path(os.environ.get("HEXBENCH_FIRMWARE", Path(__file__).resolve().parents[1] / "firmware"))
BUILD_DIR = FIRMWARE_DIR / "build"
#: Where a non-editable install keeps the host libraries it built (setup.py), for an
#: installed hexbench with no checkout beside it.
PACKAGED_DIR = Path(__file__).resolve().parent / "_firmware"
#: Profile name (module_sim.profiles) -> the tag of its builds.
PROFILE_TAG = {"v2": "v2", "thesis-2009": "thesis"}
_build_lock = threading.Lock()
_fresh: set[str] = set()  # ensure_fresh's targets found (or made) up to date in this process


class FirmwareError(HexbenchError):
    """The firmware could not be built or run."""


def build_path(kind: str, board: str, profile: str) -> Path:
    """``kind`` "elf" (ATmega162 image) or "lib" (host library) of ``board`` (comm,
    control) in ``profile``."""
    try:
        tag = PROFILE_TAG[profile]
    except KeyError:
        raise FirmwareError(f"no firmware for profile {profile!r}: expected "
                            f"{' or '.join(PROFILE_TAG)}") from None
    if kind == "elf":
        return BUILD_DIR / f"{board}-{tag}.elf"
    lib = f"libhexbot-{board}-{tag}.so"
    if not (BUILD_DIR / lib).exists() and (PACKAGED_DIR / lib).exists():
        return PACKAGED_DIR / lib
    return BUILD_DIR / lib


def ensure_fresh(target: str) -> None:
    """In a checkout, remake ``target`` of ``make -C firmware`` (``host``: the host libraries,
    ``images``: the ATmega162 images) when make finds it older than its sources, once a
    process: a source changed by a pull or an edit would otherwise run beside a stale build,
    and the Python model and the C program would part silently. An installed hexbench
    (no Makefile beside it) keeps what it was built with."""
    with _build_lock:
        if target in _fresh or not (FIRMWARE_DIR / "Makefile").exists() or shutil.which("make") is None:
            return
        if subprocess.run(["make", "-q", "-C", str(FIRMWARE_DIR), f"PYTHON={sys.executable}", target],
                          capture_output=True).returncode != 0:
            _make(target, why=" (its sources changed since the last build)")
        _fresh.add(target)


def _make(*targets: str, why: str = "") -> None:
    """``make -C firmware [targets]``; FirmwareError with make's last line if it fails."""
    r = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), f"PYTHON={sys.executable}", *targets],
                       capture_output=True, text=True)
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["(no output)"]
        raise FirmwareError(f"make -C {FIRMWARE_DIR}{''.join(' ' + t for t in targets)} failed{why}: {tail[0]}")


def ensure_built() -> None:
    """Build the firmware if any of it is missing (``make -C firmware``)."""
    with _build_lock:
        wanted = [BUILD_DIR / "hexbot-simavr", BUILD_DIR / "libhexbot-simavr.so"] + [build_path(k, b, p) for k in ("elf", "lib")
                                                  for b in ("comm", "control") for p in PROFILE_TAG]
        if all(p.exists() for p in wanted):
            return
        if not FIRMWARE_DIR.is_dir():
            raise FirmwareError(f"no firmware sources at {FIRMWARE_DIR}: this hexbench was installed "
                                "without its firmware's host libraries (they are built at install time "
                                "with a C compiler: install build-essential, then hexbench again), or "
                                "set HEXBENCH_FIRMWARE to a checkout's firmware/ directory")
        if shutil.which("avr-gcc") is None:
            raise FirmwareError("the firmware is not built and avr-gcc is not installed: install "
                                "gcc-avr avr-libc simavr libsimavr-dev (.ci/system, or make test)")
        _make()


F_CPU = 1_000_000
TIMER0_PRESCALER = 64
#: Timer0 in CTC mode counts 0..TIMER0_TOP: 156 counts of 64 us, the 9.984 ms tick.
TIMER0_TOP = 155

#: The programs' waits and loop counts in bus.timing (in ticks, or rounds): every one goes into
#: the header, and the C programs use these names where the model uses bus.timing's.
PROGRAM_TIMING = (
    "BOOT_SETTLE_TICKS", "ECHO_TIMEOUT_TICKS", "SUBSTRATE_ACK_DELAY_TICKS", "HANDSHAKE_RETRY_TICKS",
    "LOCALIZE_LISTEN_TICKS", "MAGNET_ON_LIMIT_TICKS", "SOLENOID_ON_LIMIT_TICKS", "SELFTEST_PULSE_TICKS",
    "FRAME_BYTE_TICKS",
    "BOOT_FLASH_ROUNDS", "BOOT_FLASH_TICKS", "BOOT_CIRCLE_ROUNDS", "BOOT_CIRCLE_TICKS",
    "BOOT_JTEST_ROUNDS", "BOOT_JTEST_TICKS", "YREF_FLASH_TICKS", "YREF_SHOWS",
    "THESIS_LOCALIZE_ROUNDS", "THESIS_LOCALIZE_REPEATS", "THESIS_LOCALIZE_SEND_TICKS",
    "LOCALIZE_FAILED_CIRCLE_ROUNDS", "LOCALIZE_FAILED_CIRCLE_TICKS",
    "LOCALIZE_MUX_SETTLE_TICKS", "LOCALIZE_BYTE_TICKS",
)

#: Rotation step opcodes of the generated tables.
_OPS = {"open": 1, "pos": 2, "neg": 3, "close_all": 4, "off_all": 5, "wait": 6}
_WAIT_ARG = {"t1": 1, "t2": 2, "t3": 3}
_BOARD = {Board.CONTROL: 1, Board.COMM: 2}


def ubrr(baud: int) -> int:
    """UBRR for ``baud`` at F_CPU, normal speed (16 samples per bit)."""
    return round(F_CPU / (16 * baud)) - 1


def _c_string(data: bytes) -> str:
    return '"' + "".join(chr(b) if 32 <= b < 127 and chr(b) not in '"\\' else f"\\{b:03o}"
                         for b in data) + '"'


def _pin_table(name: str, table: dict[int, pins.Pin]) -> list[str]:
    ports = ", ".join(str(pins.PORTS.index(table[k].port)) for k in range(1, 7))
    masks = ", ".join(f"0x{table[k].mask:02x}" for k in range(1, 7))
    return [f"#define {name}_PORTS {{0, {ports}}}", f"#define {name}_MASKS {{0, {masks}}}"]


def _port_masks(name: str, pin_list: list[pins.Pin]) -> list[str]:
    return [f"#define {name}_{port} 0x{mask:02x}" for port, mask in pins.port_masks(pin_list).items()]


def _rotation(name: str, steps: tuple) -> str:
    body = []
    for op, *arg in steps:
        if op == "wait":
            body.append(f"{_OPS[op]}, {_WAIT_ARG[arg[0]]}")
        else:
            body.append(f"{_OPS[op]}, {arg[0] if arg else 0}")
    return f"#define ROT_{name} {{{', '.join(body)}, 0, 0}}"


def header() -> str:
    """The text of ``hexbot_gen.h``."""
    out = [
        "/* Generated by `python -m bus.cheader` from hexbench's bus package. Do not edit:",
        " * change bus/ and regenerate (make -C firmware header). A test fails on drift. */",
        "#ifndef HEXBOT_GEN_H",
        "#define HEXBOT_GEN_H",
        "",
        "/* --- clocks and timing (spec section 3, bus/timing.py) --- */",
        f"#define HEXBOT_F_CPU {F_CPU}UL",
        f"#define TIMER0_PRESCALER {TIMER0_PRESCALER}",
        f"#define TIMER0_TOP {TIMER0_TOP}",
        f"#define TICK_NS {timing.TICK_NS}UL",
        *(f"#define {name} {getattr(timing, name)}" for name in PROGRAM_TIMING),
        "/* v2 localization at the IR baud rate: a sender slot, a listener window, a step */",
        f"#define LOCALIZE_SLOT_TICKS {timing.localize_slot_ticks(timing.Baud.IR)}",
        f"#define LOCALIZE_WINDOW_TICKS {timing.localize_window_ticks(timing.Baud.IR)}",
        f"#define LOCALIZE_STEP_TICKS {timing.localize_step_ticks(timing.Baud.IR)}",
        "/* a Walter round at the IR baud rate (ticks from the beat), its rotation timing */",
        f"#define WALTER_MUX_SETTLE_TICKS {timing.WALTER_MUX_SETTLE_TICKS}",
        f"#define WALTER_LATE_AT {timing.walter_late_at(timing.Baud.IR)}",
        f"#define WALTER_HOLD_END_AT {timing.walter_hold_end_at(timing.Baud.IR)}",
        f"#define WALTER_WINDOW_TICKS {timing.walter_window_ticks(timing.Baud.IR)}",
        f"#define WALTER_ACTUATION_AT {timing.walter_actuation_at(timing.Baud.IR)}",
        f"#define WALTER_LOG_AT {timing.walter_log_at(timing.Baud.IR)}",
        f"#define WALTER_BUSY_AT {timing.walter_busy_at(timing.Baud.IR)}",
        f"#define WALTER_ROUND_TICKS {timing.walter_round_ticks(timing.Baud.IR)}",
        "#define WALTER_ROTATION_TICKS {" + ", ".join(map(str, timing.THESIS_ROTATION_TIMING)) + "}",
        f"#define UART0_UBRR {ubrr(timing.Baud.UART0)}",
        f"#define DEBUG_UBRR {ubrr(timing.Baud.DEBUG)}",
        f"#define IR_UBRR {ubrr(timing.Baud.IR)}",
        "",
        "/* --- function codes (Table 3-7 and protocol v2, bus/functions.py) --- */",
    ]
    defined = [f for f in FUNCTIONS.values() if f.used or f.board is Board.RESERVED]
    for f in sorted(defined, key=lambda f: f.code):
        out.append(f"#define FC_{f.name} {f.code}")
    out += [f"#define ACK_UNKNOWN {ACK_UNKNOWN}", f"#define ACK_TIMEOUT {ACK_TIMEOUT}",
            f"#define ARG_UNUSED {ARG_UNUSED}", "",
            "/* Per code: board (1 control, 2 comm, 0 none), argument count, 1 if protocol v2. */",
            "#define FN_TABLE { \\"]
    for f in sorted((f for f in FUNCTIONS.values() if f.used), key=lambda f: f.code):
        out.append(f"    {{{f.code}, {_BOARD[f.board]}, {len(f.args)}, {int(f.profile == 'v2')}}}, \\")
    out += ["}", "",
            "/* LED mirrors the comm board runs with a control code (up to two, 0 = none). */",
            "#define FN_MIRRORS { \\"]
    for f in sorted((f for f in FUNCTIONS.values() if f.board is Board.CONTROL), key=lambda f: f.code):
        codes = [BY_NAME[m.lower()].code for m in f.led_mirror] + [0, 0]
        out.append(f"    {{{f.code}, {codes[0]}, {codes[1]}}}, \\")
    out += ["}", "", "/* --- pins (Tables 3-3, 3-4, 3-5; bus/pins.py): port index 0..4 = A..E,"
            " side/joint 1..6 --- */"]
    out += _pin_table("JOINT", pins.JOINT)
    out += _pin_table("MAGNET_POS", pins.MAGNET_POS)
    out += _pin_table("MAGNET_NEG", pins.MAGNET_NEG)
    out += _pin_table("LED_POS", pins.LED_POS)
    out += _pin_table("LED_NEG", pins.LED_NEG)
    out += _pin_table("LED_JOINT", pins.LED_JOINT)
    out += _pin_table("OPTICAL_SWITCH", pins.OPTICAL_SWITCH)
    out.append(f"#define DIP_PORT {pins.PORTS.index(pins.DIP_PORT)}")
    out.append("/* 1: a switch that is ON (a DIP switch, a neighbour's optical switch) reads 0 */")
    out.append(f"#define DIP_ACTIVE_LOW {int(pins.DIP_ACTIVE_LOW)}")
    out.append(f"#define OPTICAL_SWITCH_ACTIVE_LOW {int(pins.OPTICAL_SWITCH_ACTIVE_LOW)}")
    out += _port_masks("CONTROL_PULLUPS", list(pins.CONTROL_PULLUPS))
    out += _port_masks("COMM_PULLUPS", list(pins.COMM_PULLUPS))
    out += _port_masks("CONTROL_UART_PINS", list(pins.CONTROL_UART_PINS))
    out += _port_masks("CONTROL_OUTPUTS", [*pins.JOINT.values(), *pins.MAGNET_POS.values(),
                                           *pins.MAGNET_NEG.values()])
    out += _port_masks("COMM_OUTPUTS", [*pins.LED_POS.values(), *pins.LED_NEG.values(),
                                        *pins.LED_JOINT.values(), pins.IR_SEL_A, pins.IR_SEL_B,
                                        pins.IR_SEL_C])
    out.append(f"#define IR_SEL_PORT {pins.PORTS.index(pins.IR_SEL_A.port)}")
    out.append(f"#define IR_SEL_MASK 0x{pins.IR_SEL_MASK:02x}")
    out.append("/* CD4051 channel = A + 2B + 4C: the PORTA bit numbers of A, B, C */")
    out += [f"#define IR_SEL_{n}_BIT {p.bit}" for n, p in (("A", pins.IR_SEL_A), ("B", pins.IR_SEL_B),
                                                           ("C", pins.IR_SEL_C))]
    out.append(f"#define IR_CENTRE_CHANNEL {pins.IR_TRANSCEIVER_CHANNEL[pins.CENTRE]}")
    out.append("/* PORTA bits IrSel(transceiver) leaves set, transceiver 0 (centre) .. 6 */")
    out.append("#define IR_SEL_BITS {" + ", ".join(f"0x{pins.ir_select_bits(t):02x}" for t in range(7)) + "}")
    out += ["", "/* --- wire texts (bus/codec.py) --- */",
            f"#define TXT_PREAMBLE {_c_string(codec.PREAMBLE)}",
            f"#define TXT_EOL {_c_string(codec.EOL)}",
            f"#define TXT_ROLE_S {_c_string(codec.ROLE_PREFIX['S'])}",
            f"#define TXT_ROLE_M {_c_string(codec.ROLE_PREFIX['M'])}"]
    for name, text in codec.BANNERS.items():
        out.append(f"#define TXT_{name.upper()} {_c_string(text + codec.EOL)}")
    out += [f"#define TXT_ACK {_c_string(b'ACK')}", f"#define TXT_MSG {_c_string(b'MSG')}",
            f"#define TXT_POS {_c_string(codec.POS_TAG)}", f"#define TXT_ACT {_c_string(codec.ACT_TAG)}",
            f"#define TXT_LIM {_c_string(codec.LIM_TAG)}", f"#define TXT_TST {_c_string(codec.TST_TAG)}",
            f"#define TXT_VER {_c_string(codec.VER_TAG)}",
            f"#define FIRMWARE_VERSION_MAJOR {codec.FIRMWARE_VERSION[0]}",
            f"#define FIRMWARE_VERSION_MINOR {codec.FIRMWARE_VERSION[1]}",
            f"#define PROFILE_V2_BYTE {codec.PROFILE_V2}",
            f"#define TXT_SIDE {_c_string(codec.encode_side_report(0)[:-3])}",
            f"#define TXT_YREF {_c_string(codec.encode_yref_report(0)[:-3])}",
            f"#define BYTE_START 0x{codec.START[0]:02x}", f"#define BYTE_END 0x{codec.END[0]:02x}",
            f"#define BYTE_READY 0x{codec.HANDSHAKE_READY[0]:02x}",
            f"#define BYTE_LISTENING 0x{codec.HANDSHAKE_LISTENING[0]:02x}",
            f"#define PROBE_BYTES {{0x{codec.PROBE_BYTES[0]:02x}, 0x{codec.PROBE_BYTES[1]:02x}}}",
            f"#define COORD_OFFSET {codec.COORD_OFFSET}",
            "/* v2: |X|, |Y| a module can be told, keep and report (the thesis sends none) */",
            f"#define COORD_LIMIT {codec.COORD_LIMIT['v2']}",
            f"#define PC_FRAME_LEN {codec.PC_FRAME_LEN}", f"#define RELAY_FRAME_LEN {codec.RELAY_FRAME_LEN}",
            f"#define MSG1_LEN {codec.MSG1_LEN}",
            f"#define BYTE_WALTER_REQUEST 0x{codec.WALTER_REQUEST_TAG[0]:02x}",
            f"#define BYTE_WALTER_ANSWER 0x{codec.WALTER_ANSWER_TAG[0]:02x}",
            f"#define BYTE_WALTER_BUSY 0x{codec.WALTER_BUSY[0]:02x}",
            f"#define TXT_WLK {_c_string(codec.WALTER_LOG_TAG)}",
            f"#define WALTER_NO_POSITION {codec.WALTER_NO_POSITION}",
            f"#define WALTER_TABLE_CAPACITY {codec.WALTER_TABLE_CAPACITY}",
            f"#define WALTER_REQUEST_LEN {codec.WALTER_REQUEST_LEN}",
            f"#define WALTER_ANSWER_LEN {codec.WALTER_ANSWER_LEN}",
            f"#define WALTER_MODE_CW {codec.WALTER_MODE_CW}",
            f"#define WALTER_MODE_DELAY_SHIFT {codec.WALTER_MODE_DELAY_SHIFT}",
            f"#define WALTER_MODE_DELAY_MAX {codec.WALTER_MODE_DELAY_MAX}",
            *(f"#define WALTER_OP_{op.name} {int(op)}" for op in WalterOp),
            *(f"#define WALTER_FLAG_{f.name} {int(f)}" for f in WalterFlag),
            "/* what an image on the wrong board, or a board of unknown kind, prints (bus/chip.py) */"]
    for (image, found), text in codec.GUARD_TEXTS.items():
        out.append(f"#define TXT_GUARD_{image.upper()}_ON_{found.upper()} "
                   f"{_c_string(codec.PREAMBLE + text + codec.EOL)}")
    out += ["", "/* --- the EEPROM board-kind record (bus/chip.py) --- */",
            f"#define BOARD_RECORD_ADDR {chip.BOARD_RECORD_ADDR}",
            f"#define BOARD_RECORD_MAGIC0 0x{chip.BOARD_RECORD_MAGIC[0]:02x}",
            f"#define BOARD_RECORD_MAGIC1 0x{chip.BOARD_RECORD_MAGIC[1]:02x}",
            f"#define BOARD_KIND_CONTROL {int(chip.BoardKind.CONTROL)}",
            f"#define BOARD_KIND_COMM {int(chip.BoardKind.COMM)}",
            "", "/* --- rotations (bus/rotations.py): pairs (op, arg), op 1 open, 2 pos, 3 neg,",
            " * 4 close_all, 5 off_all, 6 wait (arg 1..3 = t1..t3); others act on i + arg. --- */"]
    for name in ("MCW", "MCCW", "SCW", "SCCW"):
        out.append(_rotation(name, rotations.steps(name)))
    out.append(_rotation("SCCW_AS_RAN", rotations.steps("SCCW", sccw_both_negative=True)))
    out += ["", "/* --- lattice (bus/lattice.py) --- */",
            "/* Table 4-1: cell offset (dx, dy) across global side 1..6. */",
            "#define NEIGHBOUR_DX {0, " + ", ".join(str(NEIGHBOUR_OFFSET[s][0]) for s in Side) + "}",
            "#define NEIGHBOUR_DY {0, " + ", ".join(str(NEIGHBOUR_OFFSET[s][1]) for s in Side) + "}",
            "/* Table 4-3: the mobile module's goal offset for a rotation about global joint 1..6. */"]
    for d in Direction:
        goals = [move_rule(j, d).cells(Cell(0, 0))[2] for j in Joint]
        out.append(f"#define GOAL_{d.value}_DX {{0, " + ", ".join(str(g.x) for g in goals) + "}")
        out.append(f"#define GOAL_{d.value}_DY {{0, " + ", ".join(str(g.y) for g in goals) + "}")
    out.append("/* Orientation change of a CW move (bus.rotations.orientation_after). */")
    out.append(f"#define ORIENTATION_STEP_CW {rotations.orientation_after(0, Direction.CW)}")
    out += ["", "#endif", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bus.cheader", description=__doc__.splitlines()[0])
    ap.add_argument("--check", metavar="FILE", help="exit 1 if FILE differs from the header")
    ap.add_argument("-o", "--output", metavar="FILE", help="write the header here")
    args = ap.parse_args(argv)
    text = header()
    if args.check:
        try:
            with open(args.check, encoding="ascii") as fh:
                same = fh.read() == text
        except OSError as e:
            print(f"bus.cheader: {e}", file=sys.stderr)
            return 2
        if not same:
            print(f"bus.cheader: {args.check} differs from bus/ (regenerate: make -C firmware header)",
                  file=sys.stderr)
            return 1
        return 0
    if args.output:
        with open(args.output, "w", encoding="ascii") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

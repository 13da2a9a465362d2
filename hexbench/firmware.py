"""``hexbench firmware``: build the C firmware, run it in simavr as a module, and compare it
with the Python model (the differential).

* ``hexbench firmware build``: ``make -C firmware`` (images, harness, sizes).
* ``hexbench firmware run --module ID``: one firmware module in simavr, in real time, behind
  two ptys (``--link``, ``--debug-link``): give them to ``hexbench hil`` like a real board's.
* ``hexbench firmware diff``: one PC script against the Python model (virtual clock) and the
  firmware (simavr, cycle-exact, as fast as it goes); prints the first difference of every
  stream (centre IR, side IR, debug UART, each port) with its time and exits 1 if any.
* ``hexbench firmware flash --board KIND``: back the board up, then write the fuses, the
  image and the board-kind record with avrdude (docs/firmware.md, "Flashing a board").
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

from bus import UsageError
from bus.chip import (FUSES, ISP_BITCLOCK_US, BoardKind, board_record, read_board_record, reads_disabled,
                      writes_disabled)
from bus.codec import encode_command
from bus.errors import HexbenchError
from bus.pins import COMM_PULLUPS, CONTROL_PULLUPS, port_masks
from bus.timing import NS_PER_S, TICK_NS
from hil.avrdude import Avrdude, AvrdudeError, used
from hil.isp import format_ihex, fuses_of, fuses_text

#: How far a firmware event may be from the model's: one tick (the programs only know time
#: in ticks), plus the nominal-versus-UBRR baud drift over a long line (300 vs 300.48 baud).
TOLERANCE_NS = TICK_NS + 3_000_000
#: Backups outside any checkout, so that neither git nor ``make clean`` touches them.
BACKUP_DIR = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share") / "hexbench" / "backups"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("firmware", help="the C firmware: build it, run it in simavr, diff it",
                       description=__doc__.split("\n\n")[1] if __doc__ else None)
    fsub = p.add_subparsers(dest="firmware_command", metavar="ACTION", required=True)
    b = fsub.add_parser("build", help="make -C firmware: both programs, both profiles, the harness")
    b.set_defaults(func=cmd_build)
    r = fsub.add_parser("run", help="one firmware module in simavr behind ptys, in real time")
    r.add_argument("--module", type=int, default=1, help="module id (DIP switches), default 1")
    r.add_argument("--profile", choices=["v2", "thesis-2009"], default="v2")
    r.add_argument("--link", metavar="PATH", help="symlink to the centre IR pty")
    r.add_argument("--debug-link", metavar="PATH", help="symlink to the debug UART1 pty")
    r.add_argument("--switches", type=lambda s: int(s, 0), default=0,
                   help="optical switches, bit k-1 = a neighbour on side k (default 0)")
    r.add_argument("--seconds", type=float, help="stop after this many seconds (default: Ctrl-C)")
    r.set_defaults(func=cmd_run)
    d = fsub.add_parser("diff", help="the same PC script against the model and the firmware")
    d.add_argument("--profile", choices=["v2", "thesis-2009"], default="v2")
    d.add_argument("--script", metavar="FILE",
                   help="lines '<time_ns> <hex bytes>' (default: every function once, see --print-script)")
    d.add_argument("--seconds", type=float, help="sim seconds to run (default: the script's end + 5)")
    d.add_argument("--print-script", action="store_true", help="print the default script and exit")
    d.set_defaults(func=cmd_diff)
    f = fsub.add_parser("flash", help="back a board up, then write fuses, image and board record (avrdude)",
                        description="Read the board's flash, EEPROM and fuses into a backup folder, "
                                    "then write the fuses, the image and the board-kind record, "
                                    "each verified. See docs/firmware.md, 'Flashing a board'.")
    f.add_argument("--board", choices=["comm", "control"], required=True, help="which board is on the programmer")
    f.add_argument("--profile", choices=["v2", "thesis-2009"], default="v2")
    f.add_argument("--programmer", default="avrispmkII", help="avrdude's -c (default avrispmkII)")
    f.add_argument("--port", help="avrdude's -P (default: avrdude's for the programmer, usb for an AVRISP mkII)")
    f.add_argument("--bitclock", type=float, default=ISP_BITCLOCK_US, metavar="US",
                   help=f"avrdude's -B, the ISP clock period in us (default {ISP_BITCLOCK_US}: "
                        "a 1 MHz chip needs SCK below 250 kHz)")
    f.add_argument("--backup-dir", type=Path, default=BACKUP_DIR, metavar="DIR",
                   help=f"where the backup folder goes (default {BACKUP_DIR})")
    f.add_argument("--force-board", action="store_true",
                   help="write even if the board's EEPROM record names the other board")
    f.set_defaults(func=cmd_flash)


# -- the default differential script ----------------------------------------------------------
#: (name, args, seconds it may take before the next frame) for both profiles; v2 adds its own.
_COMMON = [
    ("JxOpen", (2,), 1.5), ("JxClose", (2,), 1.5), ("JxOpenAll", (), 1.5), ("JxCloseAll", (), 1.5),
    ("SxP", (3,), 1.5), ("SxN", (4,), 1.5), ("SxOff", (3,), 1.5), ("SxP", (8,), 1.5),
    ("SxOffAll", (), 1.5), ("JTest", (1, 2), 2.0), ("SPTest", (1, 2), 2.0), ("SNTest", (1, 2), 2.0),
    ("TurnOffAll", (), 1.5), ("MCW", (1, 8, 4, 9), 2.0), ("MCCW", (2, 8, 4, 9), 2.0),
    ("SCW", (3, 8, 4, 9), 2.0), ("SCCW", (4, 8, 4, 9), 2.0), ("IrSel", (0,), 1.5),
    ("SideOnP", (1,), 1.5), ("SideOnN", (2,), 1.5), ("JointOn", (3,), 1.5), ("SideOffP", (1,), 1.5),
    ("SideOffN", (2,), 1.5), ("JointOff", (3,), 1.5), ("SideOnAllP", (), 1.5),
    ("SideOffAllP", (), 1.5), ("SideOnAllN", (), 1.5), ("SideOffAllN", (), 1.5),
    ("JointOnAll", (), 1.5), ("JointOffAll", (), 1.5), ("LOn", (), 1.5), ("LOff", (), 1.5),
    ("SidePTest", (1, 2), 2.0), ("SideNTest", (1, 2), 2.0), ("JointTest", (1, 2), 2.0),
    ("LCircle", (1, 3), 3.0), ("LColor", (1, 2), 2.0), ("LFlash1", (2, 2), 2.0),
    ("LFlash2", (2, 2), 2.0), ("LYref", (1,), 2.0), ("LYref", (2,), 2.0), ("LYref", (0,), 2.0),
    ("LMCW", (1, 8, 4, 9), 2.0), ("LMCCW", (2, 8, 4, 9), 2.0), ("LSCW", (3, 8, 4, 9), 2.0),
    ("LSCCW", (4, 8, 4, 9), 2.0), ("CW", (3, 8, 4, 9, 1, 8, 4, 9), 2.5),
    ("CCW", (3, 8, 4, 9, 2, 8, 4, 9), 2.5), (7, (), 1.5), ("Report", (), 1.5),
]
_V2 = [
    ("Select", (1, 1, 0), 1.5), ("Report", (), 1.5), ("Move", (1, 1, 2, 9, 5, 8, 4, 9), 2.5),
    ("Move", (2, 9, 2, 1, 5, 8, 4, 9), 3.5), ("Select", (1, 5, 0), 1.5), ("JxOpen", (1,), 1.5),
    ("Select", (0, 0, 0), 1.5), ("Localize", (), 1.5), ("Ref", (), 3.5), ("Report", (), 3.0),
    ("Select", (2, 128, 128), 3.0), ("LOn", (), 3.0),
]
_THESIS = [("Localize", (), 13.0), ("Ref", (), 3.5), ("Report", (), 3.0), ("LOn", (), 3.0)]
#: Last: a side selected leaves the module deaf on the centre (docs/protocol.md), so the
#: frame after it is dropped, by both.
_END = [("IrSel", (3,), 1.5), ("LOn", (), 1.5)]
#: v2 resynchronises on a '*' inside a frame that lacks its '#'; the thesis reads 9 bytes.
_GARBAGE = b"*\x01\x02*\x01\x03\x00\x00\x00\x00\x00\x00\x00#"


def default_script(profile: str, start_s: float = 11.0) -> list[tuple[int, bytes]]:
    """Every function once (and a garbled frame), from ``start_s`` on, one frame per slot."""
    steps = list(_COMMON) + (_V2 if profile == "v2" else _THESIS) + _END
    out, t = [], start_s
    for k, (fn, args, slot) in enumerate(steps):
        frame = encode_command(fn, *args) if isinstance(fn, str) else b"*" + bytes([fn]) + bytes(8) + b"#"
        out.append((int(t * NS_PER_S), frame))
        t += slot
        if k == 5:
            out.append((int(t * NS_PER_S), _GARBAGE))
            t += 2.0
    return out


# -- comparing two logs ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Difference:
    stream: str  # "ir", "irside", "debug", "port comm A", ...
    index: int  # n-th event of the stream
    model: tuple[int, str] | None  # (time_ns, value) or None: the stream ended
    firmware: tuple[int, str] | None

    def describe(self) -> str:
        def show(e):
            return "nothing" if e is None else f"{e[1]} at {e[0] / NS_PER_S:.4f} s"
        what = "value" if self.model and self.firmware and self.model[1] != self.firmware[1] else "time"
        if self.model is None or self.firmware is None:
            what = "length"
        return (f"{self.stream} #{self.index} ({what}): model {show(self.model)}, "
                f"firmware {show(self.firmware)}")


def _streams(events) -> dict[str, list[tuple[int, str]]]:
    out: dict[str, list[tuple[int, str]]] = defaultdict(list)
    for e in events:
        if e.what == "port":
            board, letter, value = e.detail.split()
            out[f"port {board} {letter}"].append((e.t_ns, value))
        elif e.what == "irside":
            out["irside"].append((e.t_ns, e.detail))
        else:
            out[e.what].append((e.t_ns, e.detail))
    return out


def compare(model, firmware, tolerance_ns: int = TOLERANCE_NS) -> list[Difference]:
    """The first difference of every stream: a value, a length, or a time beyond tolerance."""
    a, b = _streams(model), _streams(firmware)
    diffs = []
    for stream in sorted(set(a) | set(b)):
        xs, ys = a.get(stream, []), b.get(stream, [])
        for i in range(max(len(xs), len(ys))):
            x = xs[i] if i < len(xs) else None
            y = ys[i] if i < len(ys) else None
            if x is None or y is None or x[1] != y[1] or abs(x[0] - y[0]) > tolerance_ns:
                diffs.append(Difference(stream, i, x, y))
                break
    return diffs


def differential(profile: str, script, seconds: float, *, module_id: int = 1, switches: int = 0):
    """(model events, firmware events) for one script."""
    from hil.firmware import run_fast
    from module_sim.script import Event, format_script, run_script

    model = run_script(script, seconds, profile=profile, module_id=module_id, switches=switches)
    lines = run_fast(format_script(script), seconds, profile=profile, module_id=module_id,
                     switches=switches)
    return model, _after_board_init([Event.parse(line) for line in lines if line.strip()])


#: The pull-ups each image's board_init writes (bus.pins): the model's ports start there.
_PULLUPS = {"comm": port_masks(COMM_PULLUPS), "control": port_masks(CONTROL_PULLUPS)}


def _after_board_init(events):
    """The firmware's events without its board_init pull-up writes: the chip's ports reset to
    0 and board_init sets the pull-ups 2-3 ms later (after the C runtime's start-up); the
    model's ports start in that state, as the host build's do."""
    seen: set[tuple[str, str]] = set()
    out = []
    for e in events:
        if e.what == "port" and e.t_ns < TICK_NS:
            board, letter, value = e.detail.split()
            if (board, letter) not in seen and int(value, 16) == _PULLUPS[board][letter]:
                seen.add((board, letter))
                continue
        out.append(e)
    return out


# -- commands ---------------------------------------------------------------------------------------
def cmd_build(args: argparse.Namespace) -> int:
    from bus.cheader import FIRMWARE_DIR

    return subprocess.run(["make", "-C", str(FIRMWARE_DIR)]).returncode


def cmd_run(args: argparse.Namespace) -> int:
    from hil.firmware import FirmwareModule

    fw = FirmwareModule(args.module, args.profile, switches=args.switches, ir_link=args.link,
                        debug_link=args.debug_link).start()
    print(f"firmware m{args.module} ({args.profile}) in simavr: IR on {fw.ir_path}, debug UART1 on "
          f"{fw.debug_path}", flush=True)
    try:
        threading.Event().wait(args.seconds)
    except KeyboardInterrupt:
        pass
    finally:
        fw.close()
    return 0


def cmd_diff(args: argparse.Namespace) -> int:
    from module_sim.script import format_script, parse_script

    if args.script:
        try:
            with open(args.script, encoding="utf-8") as fh:
                script = parse_script(fh.read())
        except (OSError, ValueError) as exc:
            raise UsageError(f"--script {args.script}: {exc}") from None
    else:
        script = default_script(args.profile)
    if args.print_script:
        sys.stdout.write(format_script(script))
        return 0
    end = max((t for t, _ in script), default=0) / NS_PER_S
    seconds = args.seconds if args.seconds is not None else end + 5.0
    model, firmware = differential(args.profile, script, seconds)
    diffs = compare(model, firmware)
    print(f"firmware diff ({args.profile}, {len(script)} frames, {seconds:g} s): model "
          f"{len(model)} events, firmware {len(firmware)} events, tolerance "
          f"{TOLERANCE_NS / 1e6:g} ms")
    for d in diffs:
        print("  " + d.describe())
    print("same" if not diffs else f"{len(diffs)} streams differ")
    return 1 if diffs else 0


# -- flashing a board --------------------------------------------------------------------------------
def flash_image(board: str, profile: str) -> Path:
    """``firmware/build/<board>-<v2|thesis>.hex``, built (``make -C firmware images``) if missing."""
    from bus.cheader import FIRMWARE_DIR, FirmwareError, build_path

    try:
        image = build_path("elf", board, profile).with_suffix(".hex")
    except FirmwareError as exc:
        raise UsageError(str(exc)) from None
    if not image.exists():
        r = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), "images", f"PYTHON={sys.executable}"],
                           capture_output=True, text=True)
        if r.returncode != 0 or not image.exists():
            tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["(no output)"]
            raise UsageError(f"{image} is missing and 'make -C {FIRMWARE_DIR} images' failed: {tail[0]} "
                             "(it needs gcc-avr and avr-libc)")
    return image


def _backup_folder(parent: Path, board: str) -> Path:
    """A new ``<parent>/<board>-<UTC time>`` folder (``-2``, ``-3``... within one second)."""
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    for n in range(1, 100):
        folder = parent / (f"{board}-{stamp}" + (f"-{n}" if n > 1 else ""))
        try:
            folder.mkdir(parents=True)
            return folder
        except FileExistsError:
            continue
        except OSError as exc:
            raise UsageError(f"--backup-dir {parent}: {exc.strerror or exc}") from None
    raise UsageError(f"--backup-dir {parent}: no free folder name for {board}-{stamp}")


def cmd_flash(args: argparse.Namespace) -> int:
    """a. back the board up; b. refuse the other board's image; c. write fuses, image and
    board record, verified; d. say what was done."""
    kind = BoardKind[args.board.upper()]
    try:
        avrdude = Avrdude(args.programmer, args.port, bitclock_us=args.bitclock)
    except AvrdudeError as exc:
        raise UsageError(str(exc)) from None
    image = flash_image(args.board, args.profile)
    folder, backup = _back_up(avrdude, args.backup_dir, args.board)
    found = read_board_record(backup["eeprom"])
    print(f"backup: {folder} (flash {used(backup['flash'])} B in use, fuses "
          f"{fuses_text(fuses_of(backup))}, lock 0x{backup['lock'][0]:02X}, board record: "
          f"{found.name.lower() if found else 'none'})")
    if found is not None and found != kind and not args.force_board:
        raise UsageError(f"the board's EEPROM says it is a {found.name.lower()} board, not a "
                         f"{args.board} board: nothing was written (--force-board to write anyway)")
    verified = _write(avrdude, image, kind, folder, backup)
    print(f"fuses: {fuses_text(FUSES)}, {sum(verified.get(m, 0) for m in ('lfuse', 'hfuse', 'efuse'))} "
          "of 3 verified")
    print(f"flash: {image}, {verified.get('flash', 0)} B verified")
    print(f"eeprom: board record '{args.board}' at 0"
          + (", the rest as backed up" if writes_disabled(backup["lock"][0]) else "")
          + f", {verified.get('eeprom', 0)} B verified")
    return 0


def _back_up(avrdude: Avrdude, parent: Path, board: str) -> tuple[Path, dict[str, bytes]]:
    """The board's memories, read into a new folder before anything is written. A chip
    locked against reading gives a pattern, not its program: that is no backup."""
    folder = _backup_folder(parent, board)
    try:
        memories = avrdude.read(folder)
    except AvrdudeError as exc:
        shutil.rmtree(folder, ignore_errors=True)  # not a backup: no folder that looks like one
        raise UsageError(f"backup failed, nothing was written: {exc}") from None
    lock = memories["lock"][0]
    if reads_disabled(lock):
        shutil.rmtree(folder, ignore_errors=True)
        raise UsageError(f"the chip is locked (lock byte 0x{lock:02X}: LB2 programmed), so its flash and "
                         "EEPROM read back as a pattern, not a backup: nothing was written; only a chip "
                         f"erase unlocks it ({avrdude.command_line('-e')}), "
                         "and its program is lost then")
    return folder, memories


def _write(avrdude: Avrdude, image: Path, kind: BoardKind, backup: Path,
           memories: dict[str, bytes]) -> dict[str, int]:
    """Fuses, then image and board record; the bytes avrdude verified of each memory.

    The fuses go first, in a run of their own: writing flash begins with a chip erase, and
    only a programmed EESAVE keeps the EEPROM through it. A write-protected chip (lock mode
    2) takes no fuse before a chip erase: it is erased first, and its EEPROM, which that erase
    may clear, is written back whole from the backup with the record in it."""
    eeprom = board_record(kind)
    try:
        if writes_disabled(memories["lock"][0]):
            avrdude.erase()
            eeprom += memories["eeprom"][len(eeprom):]
        verified = avrdude.write_fuses(FUSES)
        with tempfile.TemporaryDirectory(prefix="hexbench-flash") as tmp:
            record = Path(tmp) / "record.hex"
            record.write_text(format_ihex(eeprom), encoding="ascii")
            return verified | avrdude.write(flash=image, eeprom=record)
    except AvrdudeError as exc:
        raise HexbenchError(f"{exc}; the board may be half-written: its previous memories are in "
                            f"{backup}, restore them with: {avrdude.restore_command(backup)}") from None

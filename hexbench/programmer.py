"""``hexbench programmer-standin``: an STK500 ISP programmer with an ATmega162 in its socket,
behind a pty, for trying ``hexbench firmware flash`` (or avrdude) without a board.

The chip starts erased with the factory fuses, or from a folder of ``<memory>.hex`` files
(``--load``: a backup of ``hexbench firmware flash``, or a folder ``--save`` wrote), and is
saved to ``--save`` when the stand-in stops. See :mod:`hil.isp`.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import threading

import serial

from bus import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("programmer-standin",
                       help="an STK500 ISP programmer with an ATmega162, behind a pty (for avrdude)",
                       description="Answer avrdude (-c stk500v1 -p m162) from a simulated ATmega162 "
                                   "on a pseudo-terminal or serial URL: to try 'hexbench firmware "
                                   "flash' without a board. See docs/firmware.md.")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true",
                       help="create a pseudo-terminal and print its path (give it to avrdude's -P)")
    where.add_argument("--port", metavar="URL", help="answer on this pyserial URL instead")
    p.add_argument("--link", metavar="PATH", help="with --pty: keep a symlink to the pty here")
    p.add_argument("--baud", type=int, default=115200, help="with --port: baud rate (default 115200)")
    p.add_argument("--load", metavar="DIR", help="start the chip from DIR/<memory>.hex (e.g. a backup)")
    p.add_argument("--save", metavar="DIR", help="write the chip's memories to DIR/<memory>.hex on exit")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until Ctrl-C)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Answer avrdude until ``--seconds`` pass or Ctrl-C; save the chip if asked."""
    from hil.isp import Atmega162, Stk500Programmer, fuses_text
    from hil.port import open_port
    from hil.pty import Pty

    chip = Atmega162()
    try:
        if args.load:
            chip.load(args.load)
        line = Pty(args.link) if args.pty else open_port(args.port, args.baud)
    except (ValueError, OSError, serial.SerialException) as exc:
        raise UsageError(str(exc)) from None
    with Stk500Programmer(line, chip) as programmer, contextlib.suppress(KeyboardInterrupt):
        where = programmer.path or args.port
        print(f"STK500 (v1) programmer stand-in, ATmega162 in its socket (fuses "
              f"{fuses_text(chip.fuses)}) on {where}: avrdude -c stk500v1 -p m162 -P {where}", flush=True)
        threading.Event().wait(args.seconds)
    print(f"{programmer.commands} commands, {chip.erases} chip erases", file=sys.stderr)
    if args.save:
        try:
            chip.save(args.save)
        except OSError as exc:
            raise UsageError(f"--save {args.save}: {exc.strerror or exc}") from None
        print(f"chip saved to {args.save}", file=sys.stderr)
    return 0

"""``hexbench hil`` (bridge real hardware onto the bus) and ``hexbench standin``."""

from __future__ import annotations

import argparse
import sys

from bus import UsageError, WallClock, add_bus_arguments, open_bus

from .args import baud


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "hil", help="bridge real modules on serial ports onto the bus",
        description="Bridge the PC's central IR transceiver on a serial port (--port) and/or a "
                    "module's debug UART1 (--debug-port --module ID) onto the bus, in real time. "
                    "Any pyserial URL: /dev/ttyUSB0, socket://host:port (ser2net raw), "
                    "rfc2217://host:port, loop://. See docs/hil.md.")
    add_bus_arguments(p)
    p.add_argument("--port", metavar="URL", help="the central IR transceiver's serial port")
    p.add_argument("--baud", type=baud, default=300, help="IR baud rate of --port (default 300)")
    p.add_argument("--debug-port", metavar="URL", help="a module's debug UART1 (control board)")
    p.add_argument("--module", type=int, metavar="ID", help="with --debug-port: the module's id (DIP switches)")
    p.add_argument("--debug-baud", type=baud, default=4800, help="baud rate of --debug-port (default 4800)")
    p.add_argument("--name", help="bridge name: events on event/<name>, centre frames from <name> "
                                  "(default hil.<port name>)")
    p.add_argument("--clock", choices=["wall", "virtual"], default="wall",
                   help="only 'wall': real hardware runs in real time")
    p.add_argument("--wait", action="store_true",
                   help="if a port is not there yet, keep retrying instead of failing")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    p.set_defaults(func=cmd_hil)

    p = sub.add_parser("standin", help="a virtual module behind a pty or serial URL (stand-in for hardware)",
                       description="Run a virtual module in real time whose centre IR channel is a "
                                   "serial line: a stand-in for a real module, to try 'hexbench hil'.")
    from .standin import add_arguments as standin_arguments
    standin_arguments(p)
    p.set_defaults(func=cmd_standin)


def cmd_hil(args: argparse.Namespace) -> int:
    from bus.keys import check_chunk
    from hil.bridge import CentreBridge, DebugBridge
    from hil.port import PORT_ERRORS

    if args.clock != "wall":
        raise UsageError("--clock virtual is not possible with real hardware: a serial port runs in "
                         "real time, so hexbench hil (and every process of a run with real modules) "
                         "uses the wall clock")
    if not args.port and not args.debug_port:
        raise UsageError("nothing to bridge: give --port URL (central IR transceiver) and/or "
                         "--debug-port URL --module ID (a module's debug UART1)")
    if args.debug_port and args.module is None:
        raise UsageError("--debug-port needs --module ID: whose control board is on that port")
    try:
        if args.name:
            check_chunk(args.name, "bridge name")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    bus = open_bus(args, WallClock())
    clock = bus.clock
    bridges = []
    try:
        try:
            if args.port:
                bridges.append(CentreBridge(bus, args.port, baud=args.baud, name=args.name)
                               .start(wait=args.wait))
            if args.debug_port:
                bridges.append(DebugBridge(bus, args.debug_port, args.module, baud=args.debug_baud)
                               .start(wait=args.wait))
        except ValueError as exc:  # pyserial: malformed URL or unknown scheme; bad module id
            raise UsageError(str(exc)) from None
        except PORT_ERRORS as exc:
            print(f"hexbench hil: error: {exc} (use --wait to keep retrying until it appears)",
                  file=sys.stderr)
            return 1
        for b in bridges:
            print(f"bridging {b.url} ({b.link.value}, {b.baud} baud) as {b.src} on fleet {args.fleet!r}",
                  flush=True)
        clock.run(timeout_s=args.seconds)
    finally:
        for b in bridges:
            b.close()
        bus.close()
    return 0


def cmd_standin(args: argparse.Namespace) -> int:
    from .standin import run
    return run(args)

"""A stand-in for hardware: a virtual module behind a serial line, in real time.

The module (:class:`module_sim.module.VirtualModule`, any profile) runs on its own
isolated bus with a :class:`~bus.clock.WallClock` and no world: its centre IR
transceiver is wired to a serial line instead of the IR medium.

* light its centre transceiver sends (``ir/tx/m<id>.comm``, transceiver 0) is written to
  the line byte by byte, each at its stop bit, so the line carries it at the IR baud rate
  in real time; side transceivers reach nobody;
* bytes read from the line reach its centre transceiver (``ir/rx/m<id>``) paced at the
  baud rate (a pty hands over a whole frame at once; a real UART would not);
* optionally its control board's debug UART1 goes out on a second line.

The line is a pseudo-terminal (:class:`hil.pty.Pty`: the bridge opens its ``path``) or
any pyserial URL. Run it as ``hexbench standin --pty``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import threading

import serial

from bus.clock import WallClock
from bus.codec import Kind
from bus.envelope import Envelope
from bus.ir import Burst
from bus.keys import board_endpoint, module_endpoint
from bus.session import SessionOptions
from bus.timing import Baud
from bus.transport import Bus
from module_sim.module import VirtualModule
from module_sim.profiles import profile as get_profile

from hil.line import ByteTimes

from .args import baud
from hil.port import LivePort, open_port
from hil.pty import Pty

_fleets = itertools.count()
LINE = "line"  # source name of light that came from the serial line


class StandIn:
    """A virtual module whose centre IR channel is a serial line.

    ``line`` is a :class:`~hil.pty.Pty` or a pyserial URL; ``debug_line`` likewise for the
    control board's debug UART1 (4800 baud). Call :meth:`start` to power the module up.

    To play a faulty or older board: ``wrong_ack=n`` flips a bit of the code byte of the
    n-th ACK it sends (a board that disagrees with its program once), and
    ``actuator_reports=False`` keeps the v2 actuator reports off the debug line (a board
    whose firmware sends none).
    """

    def __init__(self, line: Pty | str, *, module_id: int = 1, profile: str = "v2",
                 baud: int = Baud.IR, debug_line: Pty | str | None = None,
                 wrong_ack: int | None = None, actuator_reports: bool = True) -> None:
        self.profile = get_profile(profile)
        self.wrong_ack = wrong_ack
        self.actuator_reports = actuator_reports
        self.acks_sent = 0
        self._tail = b""  # the last bytes sent, to find ACK code bytes
        self.module_id = module_id
        self.baud = baud
        self.line = line
        self.debug_line = debug_line
        self.clock = WallClock()
        self.bus = Bus(self.clock, f"standin{os.getpid()}x{next(_fleets)}",
                       options=SessionOptions(isolated=True))
        self.module = VirtualModule(self.bus, module_id, self.profile, ir_baud=baud)
        self._from_line = ByteTimes(baud)
        self._bursts = 0
        self._line_free_at = 0  # when the module's (or injected) bytes leave the line
        self.sent = bytearray()  # every byte the module put on the line (and inject())
        self.received = bytearray()  # every byte read from the line
        self.booted = threading.Event()
        self._port = self._live(line, baud, self._on_line_data)
        self._debug = self._live(debug_line, Baud.DEBUG, lambda data, t: None) \
            if debug_line is not None else None
        self._thread: threading.Thread | None = None
        self._closing = False
        comm = board_endpoint(module_id, "comm")
        self.bus.subscribe(self.bus.keys.ir_tx(comm), self._on_module_light)
        self.bus.subscribe_frames(self._on_centre_frame, keyexpr=self.bus.keys.frame("centre", comm))
        if debug_line is not None:
            self.bus.subscribe_frames(self._on_debug_frame,
                                     keyexpr=self.bus.keys.frame("debug", board_endpoint(module_id, "ctrl")))

    @classmethod
    def on_pty(cls, link: str | os.PathLike[str] | None = None, *, debug_link=None,
               **kwargs) -> "StandIn":
        """A stand-in behind a new pty (and a second one for the debug UART if ``debug_link``)."""
        debug = Pty(debug_link) if debug_link is not None else None
        return cls(Pty(link), debug_line=debug, **kwargs)

    def _live(self, line: Pty | str, baud: int, on_data) -> LivePort:
        post = self.clock.post
        opener = (lambda url, b: line) if isinstance(line, Pty) else open_port
        url = line.path if isinstance(line, Pty) else line
        return LivePort(url, baud, opener=opener, now_ns=self.clock.now_ns,
                        on_data=lambda data, t: post(on_data, data, t))

    @property
    def path(self) -> str:
        """Where a bridge finds the module: the pty's path or the URL."""
        return self.line.path if isinstance(self.line, Pty) else self.line

    @property
    def debug_path(self) -> str | None:
        d = self.debug_line
        return d.path if isinstance(d, Pty) else d

    # -- life ------------------------------------------------------------------------------
    def start(self) -> "StandIn":
        """Open the line(s), start the clock thread and power the module up."""
        self._port.open()
        if self._debug is not None:
            self._debug.open()
        self._thread = threading.Thread(target=self._run, name=f"standin-m{self.module_id}",
                                        daemon=True)
        self._thread.start()
        self.clock.post(self.module.power_up)
        return self

    def _run(self) -> None:
        self.clock.run(until=lambda: self._closing)

    def wait_booted(self, timeout_s: float = 30.0) -> None:
        """Block until the module printed ``COMM. LISTENING`` (end of boot, ~8 s at 300 baud)."""
        if not self.booted.wait(timeout_s):
            raise TimeoutError(f"stand-in m{self.module_id} did not finish booting within {timeout_s} s"
                               + (f" (clock error: {self.clock.error!r})" if self.clock.error else ""))

    def hangup(self) -> None:
        """Pull the cable: close the pty (a bridge on the other end sees the port vanish)."""
        self._pty().hangup()

    def reopen(self) -> None:
        """Plug it back in: a new pty behind the same link."""
        self._pty().reopen()

    def _pty(self) -> Pty:
        if not isinstance(self.line, Pty):
            raise TypeError(f"the stand-in's line is {self.line!r}, not a pty")
        return self.line

    def inject(self, data: bytes) -> None:
        """Put raw bytes on the line as if the module's transceiver sent them (paced at the
        baud rate, after whatever the module is sending): garbage, truncated lines."""
        self.clock.post(self._inject, bytes(data))

    def _inject(self, data: bytes) -> None:
        b = self._from_line.byte_ns
        start = max(self.clock.now_ns(), self._line_free_at)
        self._send(data, [start + k * b for k in range(len(data))], b)

    def close(self) -> None:
        """Stop the module and close the line(s); idempotent."""
        if self._closing:
            return
        self._closing = True
        self.clock.stop()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for port in (self._port, self._debug):
            if port is not None:
                port.close()
        for line in (self.line, self.debug_line):
            if isinstance(line, Pty):
                line.close()
        self.bus.close()

    def __enter__(self) -> "StandIn":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the module's light -> the line (clock thread) ----------------------------------------
    def _on_module_light(self, key: str, payload: bytes) -> None:
        burst = Burst.from_dict(json.loads(payload))
        if burst.transceiver == 0:  # side transceivers face no neighbour here
            self._send(self._falsify(burst.data), burst.starts, burst.byte_ns)

    def _falsify(self, data: bytes) -> bytes:
        """``wrong_ack``: the code byte of that ACK goes out with bit 5 flipped."""
        if self.wrong_ack is None:
            return data
        out = bytearray(data)
        for i, b in enumerate(out):
            if self._tail == b"ACK":
                self.acks_sent += 1
                if self.acks_sent == self.wrong_ack:
                    out[i] = b ^ 0x20
            self._tail = (self._tail + bytes([b]))[-3:]
        return bytes(out)

    def _send(self, data: bytes, starts: list[int], byte_ns: int) -> None:
        for byte, start in zip(data, starts):
            self.clock.call_at(start + byte_ns, self._write_byte, byte)
        if starts:
            self._line_free_at = max(self._line_free_at, starts[-1] + byte_ns)

    def _write_byte(self, byte: int) -> None:
        self.sent.append(byte)
        self._port.write(bytes([byte]))

    def _on_centre_frame(self, env: Envelope) -> None:
        if env.kind == Kind.BANNER.value and env.view.get("banner") == "COMM_LST":
            self.booted.set()

    def _on_debug_frame(self, env: Envelope) -> None:
        if self._debug is not None and (self.actuator_reports or env.kind != Kind.ACTUATORS.value):
            self._debug.write(env.raw)

    # -- the line -> the module's centre transceiver (clock thread) -------------------------------
    def _on_line_data(self, data: bytes, arrived_ns: int) -> None:
        self.received += data
        b = self._from_line.byte_ns
        light = Burst(LINE, self._bursts, 0, data, self._from_line.sent(len(data), arrived_ns), b,
                      dst=module_endpoint(self.module_id), rx_transceiver=0)
        self._bursts += 1
        self.bus.put(self.bus.keys.ir_rx(module_endpoint(self.module_id)), light.to_json())


# -- command line -----------------------------------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true",
                       help="create a pseudo-terminal and print its path (give it to 'hexbench hil --port')")
    where.add_argument("--port", metavar="URL", help="use this pyserial URL as the line instead")
    p.add_argument("--link", metavar="PATH", help="with --pty: keep a symlink to the pty here")
    p.add_argument("--debug-pty", metavar="PATH",
                   help="also put the control board's debug UART1 on a pty linked here")
    p.add_argument("--module", type=int, default=1, help="module id (DIP switches), default 1")
    p.add_argument("--profile", default="v2", help="firmware profile: v2 (default) or thesis-2009")
    p.add_argument("--baud", type=baud, default=int(Baud.IR), help="IR baud rate (default 300)")
    p.add_argument("--seconds", type=float, help="stop after this many seconds (default: run until Ctrl-C)")
    p.add_argument("--wrong-ack", type=int, metavar="N",
                   help="flip a bit of the code byte of the N-th ACK sent (to see a twin check catch it)")
    p.add_argument("--no-actuator-reports", action="store_true",
                   help="keep the v2 actuator reports off the debug line (a board that sends none)")


def run(args: argparse.Namespace) -> int:
    """Run a stand-in until ``--seconds`` pass or Ctrl-C; returns an exit status."""
    standin = None
    try:
        get_profile(args.profile)
        line: Pty | str = Pty(args.link) if args.pty else args.port
        debug = Pty(args.debug_pty) if args.debug_pty else None
        standin = StandIn(line, module_id=args.module, profile=args.profile, baud=args.baud,
                          debug_line=debug, wrong_ack=args.wrong_ack,
                          actuator_reports=not args.no_actuator_reports)
        standin.start()
    except (ValueError, serial.SerialException, OSError) as exc:
        if standin is not None:  # its bus and clock must not keep the process alive
            standin.close()
        print(f"hexbench standin: error: {exc}", file=sys.stderr)
        return 2
    print(f"stand-in m{args.module} ({args.profile}, {args.baud} baud) on {standin.path}"
          + (f", debug UART1 on {standin.debug_path}" if debug else ""), flush=True)
    done = threading.Event()
    try:
        done.wait(args.seconds)
    except KeyboardInterrupt:
        pass
    finally:
        standin.close()
    return 0

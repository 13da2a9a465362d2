"""Serial bridges: real HexBot hardware on the bus.

* :class:`CentreBridge` — the PC's central IR transceiver on a serial port (300 baud).
  IR light the PC endpoint sends (``ir/tx/pc``) is written to the port; bytes from the
  port are light reaching the PC (``ir/rx/pc``), so :class:`planner_svc.endpoint.PcEndpoint`
  hears a real module exactly as it hears a virtual one, and they are framed with the
  centre-link framer and published as frames with ``origin = "serial"``.
* :class:`DebugBridge` — a module's debug UART1 (control board, 4800 baud): frames on
  ``frame/debug/m<id>.ctrl`` with ``origin = "serial"``; a v2 board's actuator reports
  (``ACT``) also become the module's ``world/actuators/m<id>`` records, so the world moves
  the real module's simulated body from its real bits.

Bytes are timestamped when they arrive (wall clock). When the port disappears, the
bridge flushes its framer (a truncated frame becomes a noise frame: nothing captured is
dropped), publishes a ``serial-fault`` event, retries with backoff and publishes
``serial-recovered`` when the port is back. Garbage becomes noise frames and the framer
resynchronises on the next frame.

All bus work happens on the bus's clock thread; the port's threads only post to it, so
somebody must run the clock (``hexbench hil`` does; in a test, ``pc.expect`` does).
"""

from __future__ import annotations

import json
from typing import Any

from bus.codec import Kind, Link
from bus.framer import Framer, Timed
from bus.ir import Burst
from bus.keys import PC, board_endpoint, module_endpoint
# the event kinds a bridge publishes on ``event/hil.<port>``
from bus.messages import SERIAL_FAULT as FAULT
from bus.messages import SERIAL_RECOVERED as RECOVERED
from bus.messages import SERIAL_TX_LOST as TX_LOST
from bus.messages import Actuators
from bus.timing import BITS_PER_BYTE, Baud
from bus.transport import Bus

from .line import ByteTimes
from .port import Backoff, LivePort, open_port, port_name

ORIGIN = "serial"



class SerialBridge:
    """Frames the bytes of one serial port and publishes them as hardware frames.

    ``src``/``dst``/``channel`` go into every envelope; events are published under
    ``name`` (default ``hil.<port name>``). Subclasses add what else the bytes are.
    """

    def __init__(self, bus: Bus, url: str, *, baud: int, link: Link, src: str | None = None,
                 dst: str = "*", channel: int | None = None, name: str | None = None,
                 backoff: Backoff = Backoff(), opener=open_port) -> None:
        if bus.clock.kind != "wall":
            raise ValueError(f"a serial bridge needs the wall clock, not the {bus.clock.kind!r} clock: "
                             "real hardware runs in real time")
        self.bus = bus
        self.url = url
        self.baud = baud
        self.link = Link(link)
        self.name = name or f"hil.{port_name(url)}"
        self.src = src or self.name
        self.dst = dst
        self.channel = channel
        self.times = ByteTimes(baud)
        self.framer = Framer(self.link)
        self.frames_published = 0
        post = bus.clock.post
        self.port = LivePort(url, baud, now_ns=bus.clock.now_ns, backoff=backoff, opener=opener,
                             on_data=lambda data, t: post(self._on_data, data, t),
                             on_fault=lambda error: post(self._on_fault, error),
                             on_recover=lambda down_s, n: post(self._on_recover, down_s, n),
                             on_tx_lost=lambda data, why: post(self._on_tx_lost, data, why))

    # -- life -------------------------------------------------------------------------------
    def start(self, *, wait: bool = False) -> "SerialBridge":
        """Open the port (raises :class:`serial.SerialException` if it cannot be opened, or
        :class:`ValueError` for a bad URL). With ``wait``, a port that is not there yet is
        reported as a fault and retried like one that disappeared."""
        self.port.open(wait=wait)
        return self

    def close(self) -> None:
        """Stop reading; whatever is pending in the framer is published first."""
        self.port.close()
        if not self.bus.closed:
            self._publish(self.framer.flush())

    @property
    def connected(self) -> bool:
        return self.port.connected

    # -- bytes in (clock thread) ----------------------------------------------------------------
    def _on_data(self, data: bytes, arrived_ns: int) -> None:
        ends = self.times.ends(len(data), arrived_ns)
        self.deliver(data, ends)
        self._publish(self.framer.feed(data, ends))

    def deliver(self, data: bytes, ends: list[int]) -> None:
        """What else the bytes are (hook for subclasses)."""

    def _publish(self, frames: list[Timed]) -> None:
        for t in frames:
            self.bus.publish_frame(t.frame, src=self.src, dst=self.dst, sim_time_ns=t.t_last_ns,
                                   first_byte_ns=t.t_first_ns - self.times.byte_ns,
                                   origin=ORIGIN, channel=self.channel)
            self.frames_published += 1
            self.on_frame(t)

    def on_frame(self, t: Timed) -> None:
        """What else a frame is (hook for subclasses)."""

    # -- faults (clock thread) -------------------------------------------------------------------
    def _on_fault(self, error: str) -> None:
        pending = self.framer.pending
        self._publish(self.framer.flush())
        b = self.port.backoff
        self.event(FAULT, error=error, flushed=pending.hex(),
                   message=f"serial port {self.url} disappeared ({error}); "
                           f"{len(pending)} pending byte(s) flushed as frames; "
                           f"retrying every {b.first_s:g}..{b.max_s:g} s")

    def _on_recover(self, down_s: float, attempts: int) -> None:
        # what the line may have carried while nobody listened: its full rate for that long
        missed = int(down_s * self.port.baud / BITS_PER_BYTE)
        was, now = self.port.first_identity, self.port.identity
        changed = was is not None and now != was
        self.event(RECOVERED, down_s=round(down_s, 3), attempts=attempts, missed_up_to=missed,
                   identity=now, identity_changed=changed,
                   message=f"serial port {self.url} is back after {down_s:.2f} s "
                           f"({attempts} attempt(s)); bridging resumed; up to {missed} byte(s) "
                           "the module sent meanwhile were not heard"
                           + (f"; it is another device now: {now} (was {was})" if changed else ""))

    def _on_tx_lost(self, data: bytes, reason: str) -> None:
        self.event(TX_LOST, lost=data.hex(),
                   message=f"{len(data)} byte(s) for {self.url} not sent: {reason}")

    def event(self, kind: str, **fields: Any) -> None:
        """An event on ``event/<name>``; ``link`` says whose port it is (a centre port carries
        the modules' answers to the PC, a debug port one board's UART1)."""
        self.bus.event(self.name, kind, port=self.url, link=self.link.value, **fields)


class CentreBridge(SerialBridge):
    """The PC's central IR transceiver on a serial port (thesis Fig. 3-32, 3-33).

    ``pc`` is the endpoint whose light goes out on the port and which hears what comes in
    (default ``pc``, the :class:`~planner_svc.endpoint.PcEndpoint`'s name).
    """

    def __init__(self, bus: Bus, url: str, *, baud: int = Baud.IR, pc: str = PC,
                 name: str | None = None, backoff: Backoff = Backoff(), opener=open_port) -> None:
        super().__init__(bus, url, baud=baud, link=Link.CENTRE, dst=pc, channel=0, name=name,
                         backoff=backoff, opener=opener)
        self.pc = pc
        self._bursts = 0
        bus.subscribe(bus.keys.ir_tx(pc), self._on_pc_light)

    def _on_pc_light(self, key: str, payload: bytes) -> None:
        burst = Burst.from_dict(json.loads(payload))
        if burst.transceiver == 0:  # the UART paces the bytes at the line's baud rate
            self.port.write(burst.data)

    def deliver(self, data: bytes, ends: list[int]) -> None:
        """Bytes from the port are IR light reaching the PC's transceiver."""
        b = self.times.byte_ns
        light = Burst(self.name, self._bursts, 0, data, [e - b for e in ends], b, dst=self.pc,
                      rx_transceiver=0)
        self._bursts += 1
        self.bus.put(self.bus.keys.ir_rx(self.pc), light.to_json())


class DebugBridge(SerialBridge):
    """A module's debug UART1 (its control board's terminal output) on a serial port."""

    def __init__(self, bus: Bus, url: str, module_id: int, *, baud: int = Baud.DEBUG,
                 name: str | None = None, backoff: Backoff = Backoff(), opener=open_port) -> None:
        if not 1 <= module_id <= 255:
            raise ValueError(f"module id {module_id} is out of range: DIP switches give 1..255")
        super().__init__(bus, url, baud=baud, link=Link.DEBUG, src=board_endpoint(module_id, "ctrl"),
                         dst="terminal", name=name, backoff=backoff, opener=opener)
        self.module_id = module_id
        self.reports = 0

    def on_frame(self, t: Timed) -> None:
        """An actuator report is the module's actuator state: the board's own bits (LEDs and
        the IR multiplexer are the comm board's, which reports none)."""
        if t.frame.kind is not Kind.ACTUATORS:
            return
        v = t.frame.view
        self.reports += 1
        self.bus.put(self.bus.keys.actuators(module_endpoint(self.module_id)), Actuators(
            module=module_endpoint(self.module_id), sim_time_ns=t.t_last_ns,
            joints_open=list(v["joints_open"]), magnets=list(v["magnets"]), led_pos=[False] * 6,
            led_neg=[False] * 6, led_joint=[False] * 6, ir_channel=None, origin=ORIGIN).to_json())


__all__ = ["CentreBridge", "DebugBridge", "FAULT", "ORIGIN", "RECOVERED", "SerialBridge", "TX_LOST"]

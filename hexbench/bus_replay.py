"""Bus replay: a recording's frames back onto the bus with their original timing (the role of
python-can's ``can.player``), filtered by link.

* Frames of the ``pc`` link travel the way the PC sent them: as IR light, through
  :meth:`planner_svc.endpoint.PcEndpoint.send_raw` (bursts on ``ir/tx/pc``, then the frame on
  ``frame/pc/pc``), so virtual and real modules receive them like any command.
* Frames of other links are republished as envelopes on their ``frame/<link>/<src>`` keys (a
  monitor or recorder sees them; modules listen to light, not to frames).

Every replayed frame carries ``origin = "replay"``. Each is scheduled on the bus clock at its
recorded first-byte time: on a virtual clock at exactly the recorded sim time; on a wall
clock after a short lead-in, with the gaps between frames divided by ``speed`` (the bytes
themselves still take their wire time).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from bus.codec import Link, parse
from bus.envelope import Envelope
from bus.transport import Bus
from planner_svc.endpoint import PcEndpoint

from recordings.reader import read_frames

ORIGIN = "replay"
#: Links whose frames are sent as IR light by a PC endpoint.
PC_LINKS = frozenset({Link.PC.value})
LINKS = tuple(link.value for link in Link)


def parse_links(text: str | Iterable[str]) -> tuple[str, ...]:
    """``"pc,side"`` (or a list) -> ``("pc", "side")``, checked against the known links."""
    items = [x.strip() for x in (text.split(",") if isinstance(text, str) else text) if x.strip()]
    bad = [x for x in items if x not in LINKS]
    if bad or not items:
        raise ValueError(f"unknown link(s) {', '.join(bad) or '(none given)'}: expected some of {', '.join(LINKS)}")
    return tuple(dict.fromkeys(items))


def first_byte_ns(env: Envelope) -> int:
    """When a recorded frame's first byte started (its last byte's time if unknown)."""
    return env.first_byte_ns if env.first_byte_ns is not None else env.sim_time_ns


def recorded_baud(env: Envelope, default: int = 300) -> int:
    """The baud rate a frame was sent at, from its wire time (10 bits a byte)."""
    if env.first_byte_ns is None or env.sim_time_ns <= env.first_byte_ns or not env.raw:
        return default
    return max(1, round(len(env.raw) * 10 * 1_000_000_000 / (env.sim_time_ns - env.first_byte_ns)))


@dataclass
class BusReplay:
    """Schedules the frames of ``links`` from a recording on ``bus``'s clock.

    Create it before the run starts (a PC endpoint subscribes when it is made), call
    :meth:`schedule`, then run the clock until :attr:`done`.
    """

    bus: Bus
    frames: list[Envelope]
    links: tuple[str, ...] = ("pc",)
    speed: float = 1.0
    pcs: dict[str, PcEndpoint] = field(default_factory=dict)
    sent: int = 0
    end_ns: int = 0  # when the last replayed byte ends (known once everything is sent)

    @classmethod
    def from_recording(cls, bus: Bus, path: str | Path, *, links: Iterable[str] = ("pc",), speed: float = 1.0,
                       pcs: dict[str, PcEndpoint] | None = None) -> "BusReplay":
        """The frames of ``links`` in ``path`` (recorded order), with a PC endpoint per PC-link
        source (``pcs`` reuses existing ones, e.g. a :class:`hexbench.virtual_run.VirtualRun`'s)."""
        links = parse_links(links)
        if speed <= 0:
            raise ValueError(f"speed must be positive, got {speed}")
        chosen = [e for e in read_frames(path) if e.link in links]
        out = cls(bus, chosen, links, speed, dict(pcs or {}))
        for e in chosen:
            if e.link in PC_LINKS and e.src not in out.pcs:
                out.pcs[e.src] = PcEndpoint(bus, name=e.src, baud=recorded_baud(e))
        return out

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def done(self) -> bool:
        """Every frame handed to the bus and the last byte on the wire."""
        return self.sent == len(self.frames) and self.bus.clock.now_ns() >= self.end_ns

    def schedule(self, *, start_ns: int | None = None) -> int:
        """Put every frame on the clock. A virtual clock replays at the recorded times
        (``start_ns`` None); otherwise the recording's first frame goes at ``start_ns``
        (default: now + 50 ms) and later ones ``speed`` times faster than recorded.
        Returns when the last frame starts."""
        clock = self.bus.clock
        if not self.frames:
            self.end_ns = clock.now_ns()
            return self.end_ns
        first = min(first_byte_ns(e) for e in self.frames)
        if start_ns is None and getattr(clock, "kind", "") == "virtual" and self.speed == 1.0:
            offset, origin = 0, 0
        else:
            offset = clock.now_ns() + 50_000_000 if start_ns is None else start_ns
            origin = first
        last = 0
        for env in self.frames:
            t = offset + int((first_byte_ns(env) - origin) / self.speed)
            clock.call_at(t, self._send, env)
            last = max(last, t)
        return last

    def _send(self, env: Envelope) -> None:
        clock = self.bus.clock
        if env.link in PC_LINKS:
            end = self.pcs[env.src].send_raw(env.raw, origin=ORIGIN)
        else:
            now = clock.now_ns()
            wire = env.sim_time_ns - first_byte_ns(env)
            self.bus.publish_frame(parse(Link(env.link), env.raw), src=env.src, dst=env.dst, sim_time_ns=now + wire,
                                   first_byte_ns=now, channel=env.channel, origin=ORIGIN)
            end = now + wire
        self.sent += 1
        self.end_ns = max(self.end_ns, end)

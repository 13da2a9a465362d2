"""Twins: the world's copy of a real module, and the live differential against its board.

A real board shows the world only what comes out of its serial ports. Its twin, a
:class:`~module_sim.module.VirtualModule` with the board's id and profile at the board's cell
(``origin = "twin"``), fills in the rest: it hears what the board hears from the PC and what
virtual neighbours send toward that cell, and its side light, optical switches and (for a
board that sends no actuator reports) actuator bits are what the world uses. Its centre
light stays in the world: the PC hears the board.

:class:`TwinCheck` holds the two to the same bytes, on one link: the board's answers on the
centre channel (through a :class:`hil.bridge.CentreBridge`), or its debug lines and actuator
reports (through a :class:`hil.bridge.DebugBridge`), against the twin's, in order; banners
(the board booted before the run) and noise are left out. A difference is

* ``twin-view`` when it is a report of what a module learns from its neighbours (a location
  report) and the twin has taken in side light, which the board beside virtual neighbours
  never gets: the twin may rightly know more, so its view is the one to use, and the event
  says so;
* ``twin-diverged`` otherwise, once per module (later differences are counted): the board
  and the program it should run disagree. The run goes on with the board's answer.

While the board's port is down (a cable pulled, an adapter replugged: :meth:`TwinCheck.line_down`
and :meth:`TwinCheck.line_up`), what the board sends is heard by nobody: the twin's answers
of that time are not compared (they are counted), so the two stay in step once it is back.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Callable

from bus.codec import Kind
from bus.envelope import Envelope
from bus.keys import module_endpoint
from bus.transport import Bus

from .module import VirtualModule

DIVERGED = "twin-diverged"
VIEW = "twin-view"
#: Centre-channel frames that are not answers to the PC.
_SKIPPED = frozenset({Kind.BANNER.value, Kind.NOISE.value})
#: Answers that carry what a module learned over side IR (its location).
_LEARNED = frozenset({Kind.POSITION.value, Kind.SIDE_REPORT.value, Kind.YREF_REPORT.value})


@dataclass
class Difference:
    """One answer that differs: what the twin sent and what the board sent."""

    module: str
    index: int  # answers compared before it
    expected: Envelope  # the twin's
    received: Envelope  # the board's
    explained: bool  # a location the twin learned from side light the board could not hear

    def describe(self, since_ns: int = 0) -> str:
        """One line; times in seconds since ``since_ns`` (the run's start)."""
        at = (self.received.sim_time_ns - since_ns) / 1e9
        return (f"{self.module}: {self.received.link} frame {self.index + 1} at {at:.3f} s: "
                f"the board sent {self.received.frame.describe()} ({self.received.raw.hex()}), its "
                f"twin {self.expected.frame.describe()} ({self.expected.raw.hex()})")


@dataclass
class TwinCheck:
    """Compares what ``twin`` sends on ``link`` (``"centre"`` or ``"debug"``) with what its
    board sends from ``real_src``: the bridge of the port the board alone is on for the
    centre channel (``hil.ttyUSB0``); for the debug UART the board's own ``m<id>.ctrl``,
    told apart from the twin's by ``origin``."""

    bus: Bus
    twin: VirtualModule
    real_src: str
    link: str = "centre"
    on_difference: Callable[[Difference], None] | None = None
    compared: int = 0
    differences: list[Difference] = field(default_factory=list)
    unheard: int = 0  # the twin's answers while the board's port was down: not compared
    _expected: deque = field(default_factory=deque)  # (envelope, side bytes heard by then)
    _received: deque = field(default_factory=deque)
    _down: bool = False
    _up_ns: int = 0  # when the board's port came back

    def __post_init__(self) -> None:
        keys = self.bus.keys
        board = self.twin.comm if self.link == "centre" else self.twin.ctrl
        twin_key = keys.frame(self.link, board.name)
        board_key = keys.frame(self.link, self.real_src)
        if twin_key == board_key:
            self.bus.subscribe_frames(self._on_frame, keyexpr=twin_key)
        else:
            self.bus.subscribe_frames(self._on_twin, keyexpr=twin_key)
            self.bus.subscribe_frames(self._on_board, keyexpr=board_key)

    def _on_frame(self, env: Envelope) -> None:
        (self._on_twin if env.origin == "twin" else self._on_board)(env)

    @property
    def module(self) -> str:
        return module_endpoint(self.twin.id)

    @property
    def diverged(self) -> list[Difference]:
        return [d for d in self.differences if not d.explained]

    def line_down(self) -> None:
        """The board's port went away: the twin's answers still waiting for the board's were
        lost with it, and so are those to come until :meth:`line_up`."""
        self._down = True
        self.unheard += len(self._expected)
        self._expected.clear()

    def line_up(self, at_ns: int) -> None:
        """The board's port is back since ``at_ns``: an answer that began before was not heard
        whole (the bridge's framer made noise of its tail)."""
        self._down = False
        self._up_ns = at_ns

    def _on_twin(self, env: Envelope) -> None:
        if env.kind in _SKIPPED:
            return
        began = env.first_byte_ns if env.first_byte_ns is not None else env.sim_time_ns
        if not self._received and (self._down or began < self._up_ns):
            self.unheard += 1  # the board's copy went out while nobody listened
            return
        self._expected.append((env, self.twin.side_bytes_heard))
        self._compare()

    def _on_board(self, env: Envelope) -> None:
        if env.kind not in _SKIPPED:
            self._received.append(env)
            self._compare()

    def _compare(self) -> None:
        while self._expected and self._received:
            (expected, heard), received = self._expected.popleft(), self._received.popleft()
            index = self.compared
            self.compared += 1
            if expected.raw == received.raw:
                continue
            d = Difference(self.module, index, expected, received,
                           explained=heard > 0 and expected.kind in _LEARNED)
            first = not d.explained and not self.diverged
            self.differences.append(d)
            if d.explained or first:
                self.bus.event(self.module, VIEW if d.explained else DIVERGED, link=self.link,
                               index=index, expected=expected.raw.hex(), received=received.raw.hex(),
                               expected_kind=expected.kind, received_kind=received.kind,
                               board=self.real_src, message=d.describe(self.bus.clock.started_ns))
            if self.on_difference is not None:
                self.on_difference(d)

    def summary(self) -> str:
        """One line for the end of a run."""
        bad = self.diverged
        what = "answers" if self.link == "centre" else "debug lines"
        text = (f"twin check {self.module} ({self.link}): {self.compared} {what} compared with the "
                f"board's ({self.real_src})")
        if bad:
            text += f"; {len(bad)} differ: first {bad[0].describe(self.bus.clock.started_ns)}"
        else:
            text += "; no divergence"
        seen = len(self.differences) - len(bad)
        if seen:
            text += f"; {seen} where the twin heard side light the board could not (its view used)"
        if self.unheard:
            text += f"; {self.unheard} of the twin's not compared: the board's port was down"
        return text

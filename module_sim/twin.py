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
    _expected: deque = field(default_factory=deque)  # (envelope, side bytes heard by then)
    _received: deque = field(default_factory=deque)

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

    def _on_twin(self, env: Envelope) -> None:
        if env.kind not in _SKIPPED:
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
        return text

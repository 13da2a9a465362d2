"""Electrical energy from actuator on-times (thesis §4.4.2, spec §8).

What is integrated (details and the comparison with the thesis in docs/physics.md):

* **magnets**: each energised side magnet draws 24 V x 2 A = 48 W while on. A side with
  both relays on (value 2, a fault) counts as one energised coil: the real draw of a
  relay fight is not known, and the fault is reported by the physics.
* **solenoids**: each energised (open) joint solenoid draws 5 V x 0.5 A = 2.5 W.
* **logic**: drive circuit + microcontroller + communication, 5 V x 3 A = 15 W, charged
  once per move for the move's *actuation interval*: from the first actuator a
  participant energised for the move until the last one is released (or the arrival,
  whichever is first). The always-on idle draw is neglected, as in the thesis.

The meter is exact: actuator states are piecewise constant between changes, so every
integral is a sum of (power x duration) over segments.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field
from typing import Iterable, Sequence

from bus.timing import NS_PER_S
from module_sim.physics import MAG_OFF, MoveCompleted

#: §4.4.2: one magnet at 24 V, 2 A.
MAGNET_W = 24.0 * 2.0
#: §4.4.2: one solenoid at 5 V, 0.5 A.
SOLENOID_W = 5.0 * 0.5
#: §4.4.2: drive circuit, microcontroller and communication at 5 V, 3 A.
LOGIC_W = 5.0 * 3.0


@dataclass(frozen=True)
class EnergyBreakdown:
    """Energy in joules, split as in :class:`bus.messages.Energy` ``by_actuator``."""

    magnets_j: float = 0.0
    solenoids_j: float = 0.0
    logic_j: float = 0.0

    @property
    def total_j(self) -> float:
        return self.magnets_j + self.solenoids_j + self.logic_j

    def by_actuator(self) -> dict[str, float]:
        return {"magnets": self.magnets_j, "solenoids": self.solenoids_j, "logic": self.logic_j}

    def __add__(self, other: "EnergyBreakdown") -> "EnergyBreakdown":
        return EnergyBreakdown(self.magnets_j + other.magnets_j,
                               self.solenoids_j + other.solenoids_j,
                               self.logic_j + other.logic_j)


@dataclass
class _Track:
    """One module's actuator history as change points: (time, open joints, magnets on)."""

    times: list[int] = field(default_factory=list)
    joints: list[int] = field(default_factory=list)
    magnets: list[int] = field(default_factory=list)
    #: coil-seconds of magnets and of joints from the first change point to each one: a
    #: span's energy is a difference of two, not a walk over the whole history
    mag_s: list[float] = field(default_factory=list)
    joint_s: list[float] = field(default_factory=list)

    def active(self, k: int) -> bool:
        return self.joints[k] > 0 or self.magnets[k] > 0

    def append(self, t_ns: int, joints: int, magnets: int) -> None:
        if self.times:
            dt = (t_ns - self.times[-1]) / NS_PER_S
            self.mag_s.append(self.mag_s[-1] + self.magnets[-1] * dt)
            self.joint_s.append(self.joint_s[-1] + self.joints[-1] * dt)
        else:
            self.mag_s.append(0.0)
            self.joint_s.append(0.0)
        self.times.append(t_ns)
        self.joints.append(joints)
        self.magnets.append(magnets)

    def coil_seconds(self, t_ns: int) -> tuple[float, float]:
        """Magnet and joint coil-seconds from the first change point to ``t_ns``."""
        k = bisect.bisect_right(self.times, t_ns) - 1
        if k < 0:
            return 0.0, 0.0
        dt = (t_ns - self.times[k]) / NS_PER_S
        return self.mag_s[k] + self.magnets[k] * dt, self.joint_s[k] + self.joints[k] * dt


class EnergyMeter:
    """Integrates actuator on-times per module; per move on request, per run always.

    Feed it the same ``on_actuators`` calls as :class:`module_sim.physics.MotionJudge`
    and call :meth:`record_move` with every ``MoveCompleted``.
    """

    def __init__(self, magnet_w: float = MAGNET_W, solenoid_w: float = SOLENOID_W,
                 logic_w: float = LOGIC_W) -> None:
        self.magnet_w, self.solenoid_w, self.logic_w = magnet_w, solenoid_w, logic_w
        self._tracks: dict[str, _Track] = {}
        self._moves_logic_j = 0.0
        self._moves: list[tuple[MoveCompleted, EnergyBreakdown]] = []

    # --- input --------------------------------------------------------------------
    def on_actuators(self, module: str, t_ns: int, joints_open: Sequence[bool],
                     magnets: Sequence[int]) -> None:
        """A module's new actuator state (body frame) at ``t_ns``."""
        tr = self._tracks.setdefault(module, _Track())
        if tr.times and t_ns < tr.times[-1]:
            raise ValueError(f"{module}: time went backwards ({t_ns} < {tr.times[-1]})")
        nj = sum(bool(j) for j in joints_open)
        nm = sum(m != MAG_OFF for m in magnets)  # 2 (relay fight) counts as one coil
        if tr.times and tr.times[-1] == t_ns:  # same instant: the last state wins
            tr.joints[-1], tr.magnets[-1] = nj, nm
        elif not tr.times or (tr.joints[-1], tr.magnets[-1]) != (nj, nm):
            tr.append(t_ns, nj, nm)

    def record_move(self, move: MoveCompleted) -> EnergyBreakdown:
        """The energy of a finished move; its logic share is added to the run total."""
        e = self.move_energy(move)
        self._moves_logic_j += e.logic_j
        self._moves.append((move, e))
        return e

    # --- queries ------------------------------------------------------------------
    def actuator_energy(self, modules: Iterable[str] | None = None, start_ns: int = 0,
                        end_ns: int | None = None) -> EnergyBreakdown:
        """Magnet and solenoid energy of ``modules`` (default all) over [start, end]."""
        mags = sols = 0.0
        for mid in (self._tracks if modules is None else modules):
            tr = self._tracks.get(mid)
            if tr is None or not tr.times:
                continue
            # an open last segment with no end adds nothing
            hi = tr.times[-1] if end_ns is None else end_ns
            lo = max(start_ns, tr.times[0])
            if hi > lo:
                m_hi, j_hi = tr.coil_seconds(hi)
                m_lo, j_lo = tr.coil_seconds(lo)
                mags += (m_hi - m_lo) * self.magnet_w
                sols += (j_hi - j_lo) * self.solenoid_w
        return EnergyBreakdown(mags, sols, 0.0)

    def burst_start(self, module: str, at_ns: int) -> int | None:
        """When the module's current run of energised actuators began, if it is active at
        ``at_ns`` (None if everything was off then)."""
        tr = self._tracks.get(module)
        if tr is None or not tr.times:
            return None
        k = bisect.bisect_right(tr.times, at_ns) - 1
        if k < 0 or not tr.active(k):
            return None
        while k > 0 and tr.active(k - 1):
            k -= 1
        return tr.times[k]

    def last_release(self, module: str, start_ns: int, end_ns: int) -> int | None:
        """The last moment in [start, end] the module was active (end if still active)."""
        tr = self._tracks.get(module)
        if tr is None:
            return None
        last = None
        times = tr.times
        # segments ending before ``start`` cannot count: begin at the one holding it (a walk
        # from the first change point made a long run's moves quadratic)
        for k in range(max(0, bisect.bisect_left(times, start_ns) - 1), len(times)):
            t = times[k]
            if t > end_ns:
                break
            if tr.active(k):
                seg_end = tr.times[k + 1] if k + 1 < len(tr.times) else end_ns
                if seg_end >= start_ns:
                    last = min(seg_end, end_ns)
        return last

    def move_window(self, move: MoveCompleted) -> tuple[int, int, int]:
        """(start, actuation end, arrival) of a move: start is the earliest burst start of
        any participant active when the drive began."""
        starts = [s for p in move.participants
                  if (s := self.burst_start(p, move.started_ns)) is not None]
        start = min(starts, default=move.started_ns)
        ends = [e for p in move.participants
                if (e := self.last_release(p, start, move.t_ns)) is not None]
        return start, max(ends, default=move.started_ns), move.t_ns

    def move_energy(self, move: MoveCompleted) -> EnergyBreakdown:
        """Actuator energy of all participants over the move window, plus the logic draw
        over its actuation interval."""
        start, act_end, arrival = self.move_window(move)
        act = self.actuator_energy(move.participants, start, arrival)
        return EnergyBreakdown(act.magnets_j, act.solenoids_j,
                               self.logic_w * (act_end - start) / NS_PER_S)

    def run_energy(self, t_ns: int) -> EnergyBreakdown:
        """All actuator energy of the run up to ``t_ns`` plus the logic of recorded moves."""
        act = self.actuator_energy(None, 0, t_ns)
        return EnergyBreakdown(act.magnets_j, act.solenoids_j, self._moves_logic_j)

    def per_module(self, t_ns: int) -> dict[str, EnergyBreakdown]:
        """Actuator energy per module up to ``t_ns`` (logic is per move, not per module)."""
        return {m: self.actuator_energy([m], 0, t_ns) for m in self._tracks}

    @property
    def moves(self) -> list[tuple[MoveCompleted, EnergyBreakdown]]:
        return list(self._moves)

"""Physics of a HexBot rotation: actuator timelines in, moves (or refusals) out.

Pure and deterministic: no clocks, no bus. The World feeds every module's actuator
state changes (body frame, with their sim time) to a :class:`MotionJudge` and publishes
what it returns. The rules are explained, with their reasons, in ``docs/physics.md``;
in short:

* **Latches.** Each vertex of a module carries one pull-type solenoid (the male pin).
  The pin at vertex ``k`` latches into the female connector of the neighbour across
  side ``k-1`` -- the side that *ends* at that vertex. A shared edge therefore has two
  latches, one at each of its vertices, one owned by each module. A latch holds unless
  its owner energises (opens) that solenoid. This is the only convention under which
  every solenoid the Appendix A firmware opens in MCW/MCCW/SCW/SCCW has a purpose.
* **Drive.** A module whose two sides next to one vertex ``P`` are both negative is
  trying to rotate about ``P``. The rotation is *driven* while: it is not the fixed
  module; an immobile module (the substrate) touches ``P``; Table 4-3's goal and sweep
  cells are free; the substrate's side facing the mobile is negative (repulsion) and
  its other side at ``P`` positive (attraction); and every latch between the mobile and
  any neighbour is released except the one at ``P`` (the pin on the rotation axis: a
  hinge, allowed either way).
* **Timing.** The drive must hold for :data:`BREAKAWAY_NS` (3 ticks) to break the
  mobile away; after that the move is committed, its goal and sweep cells reserved.
  The attraction (mobile pair negative, substrate attract side positive) must last
  :data:`CARRY_NS` (10 ticks) from the drive start, else the module stalls (a
  :class:`Fault`, it falls back). The module reaches the goal :data:`ROTATION_NS`
  (120 degrees at 9.52 rad/s, ~220 ms) after the drive started.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any, Iterable, Sequence, Union

from bus.lattice import Cell, Direction, Joint, MoveRule, Side, move_rule
from bus.rotations import RotationArgs, orientation_after, rotation_arguments  # noqa: F401 (re-exported)
from bus.timing import NS_PER_S, TICK_NS

# --- constants -----------------------------------------------------------------------
#: Angular speed of a rotation (§3.2.4).
ANGULAR_SPEED_RAD_S = 9.52
#: A move turns the module by 120 degrees about the pivot vertex.
ROTATION_RAD = 2 * math.pi / 3
#: Time from drive start to arrival in the goal cell: 2.094 rad / 9.52 rad/s = 220 ms.
ROTATION_NS = round(ROTATION_RAD / ANGULAR_SPEED_RAD_S * NS_PER_S)
#: Repulsion with the latches released must last this long to break the mobile away.
#: The firmware's shortest phase with magnets on and latches released is t2 = 4 ticks;
#: ``DelayXts(4)`` may last only a little over 3 ticks (the first tick can come right
#: after ``ts = 0``), so 3 ticks is the largest threshold every thesis timing passes.
BREAKAWAY_NS = 3 * TICK_NS
#: The attraction must act until the mobile is about half-way (60 degrees take 110 ms at
#: 9.52 rad/s), where the attracting side takes over. The thesis estimates magnets on
#: "nearly 100 ms"; the firmware keeps them t2 + t3 = 13 ticks. 10 ticks, tick-rounded.
CARRY_NS = 10 * TICK_NS

#: Magnet states in :class:`bus.messages.Actuators`.
MAG_OFF, MAG_POS, MAG_NEG, MAG_BOTH = 0, 1, -1, 2


@dataclass(frozen=True)
class PhysicsParams:
    """Timing thresholds of the motion model (defaults justified above)."""

    rotation_ns: int = ROTATION_NS
    breakaway_ns: int = BREAKAWAY_NS
    carry_ns: int = CARRY_NS

    def __post_init__(self) -> None:
        if not 0 < self.breakaway_ns <= self.carry_ns <= self.rotation_ns:
            raise ValueError("need 0 < breakaway_ns <= carry_ns <= rotation_ns")


# --- geometry of a rotation ---------------------------------------------------------
def rotation_degrees(direction: Direction | str) -> float:
    """Signed rotation angle of a move (positive = counter-clockwise, as in
    :func:`bus.lattice.rotate_about_vertex`). Table 4-3's CW is geometric clockwise."""
    return -120.0 if Direction(direction) is Direction.CW else 120.0


def substrate_cell(mobile: Cell, pivot: Joint | int, direction: Direction | str) -> Cell:
    """Where the substrate sits: across side j for CW, across side j-1 for CCW
    (the two cells touching vertex j besides the mobile's own)."""
    j = Joint.of(pivot)
    side = j if Direction(direction) is Direction.CW else j - 1
    return mobile.neighbour(side)


def latch_joint(side: int) -> Joint:
    """The solenoid (vertex) whose pin latches a module to its neighbour across
    ``side``: the vertex where the side ends (side k runs from joint k to joint k+1)."""
    return Joint.of(side + 1)


# --- outcomes -----------------------------------------------------------------------
class Reason(str, Enum):
    """Why a move was refused or a fault raised (``MoveRefused.reason``)."""

    FIXED_MODULE = "fixed-module"
    BOTH_RELAYS = "both-relays"
    SUPPORTING_MOVE = "supporting-move"
    MISSING_SUBSTRATE = "missing-substrate"
    SUBSTRATE_MOVING = "substrate-moving"
    GOAL_OCCUPIED = "goal-occupied"
    SWEEP_OCCUPIED = "sweep-occupied"
    WRONG_POLARITY = "wrong-polarity"
    NO_ATTRACTION = "no-attraction"
    NEIGHBOUR_LATCHED = "neighbour-latched"
    TOO_SHORT = "too-short"
    STALLED = "stalled"


@dataclass(frozen=True)
class _Move:
    module: str
    t_ns: int
    started_ns: int
    from_cell: Cell
    to_cell: Cell
    pivot_joint_global: Joint
    direction: Direction


@dataclass(frozen=True)
class MoveStarted(_Move):
    """The mobile broke away at ``t_ns``; the rotation began at ``started_ns``."""

    substrate: str


@dataclass(frozen=True)
class MoveCompleted(_Move):
    """The module arrived in ``to_cell`` at ``t_ns``. ``participants``: the mobile, the
    substrate and the mobile's other neighbours when it started (energy attribution)."""

    orientation_before: int
    orientation_after: int
    substrate: str
    participants: tuple[str, ...]


@dataclass(frozen=True)
class _Report:
    module: str
    t_ns: int
    reason: Reason
    detail: str
    data: dict[str, Any] = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class MoveRefused(_Report):
    """An attempt (a negative magnet pair) ended without a move; ``reason`` is the
    furthest check the attempt failed (see docs/physics.md)."""


@dataclass(frozen=True)
class Fault(_Report):
    """A physical fault: both relays of a side on, or a rotation stalled half-way."""


Outcome = Union[MoveStarted, MoveCompleted, MoveRefused, Fault]


# --- the judge ----------------------------------------------------------------------
@dataclass(frozen=True)
class ModuleSpec:
    """A module's initial pose: ``orientation`` is Yref (global side = body side + o)."""

    id: str
    cell: Cell
    orientation: int = 0
    fixed: bool = False


@dataclass(frozen=True)
class _Plan:
    """A geometrically possible move for an attempt (what the drive would do)."""

    rule: MoveRule
    substrate: str
    goal: Cell
    sweep: tuple[Cell, ...]
    repel_body: Side  # substrate body side facing the mobile
    attract_body: Side  # substrate body side at the pivot facing the goal


@dataclass(frozen=True)
class Verdict:
    """The judgement of one attempt at one instant (:meth:`MotionJudge._evaluate`).

    Driven: ``plan`` is the move the drive makes (``ok``). Refused: ``reason``,
    ``detail`` and ``data`` say why, as a :class:`MoveRefused` will; ``rank`` is how far
    the checks got (the ranks below): an attempt that ends without a move reports the
    furthest refusal it met."""

    plan: _Plan | None = None
    rank: int = -1
    reason: Reason | None = None
    detail: str = ""
    data: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def ok(self) -> bool:
        return self.plan is not None

    @classmethod
    def refused(cls, rank: int, reason: Reason, detail: str, data: dict[str, Any]) -> "Verdict":
        return cls(None, rank, reason, detail, data)


@dataclass(slots=True)
class _Trial:
    """One evaluation under way: the mobile and its pivot, then what each check finds
    (the substrate and the rule, the polarity sides) for the checks after it."""

    mod: _Module
    pivot_body: Joint
    j: Joint  # the pivot, global
    sub: _Module | None = None
    rule: MoveRule | None = None
    goal: Cell | None = None
    sweep: tuple[Cell, ...] = ()
    repel_body: Side | None = None
    attract_body: Side | None = None

    @property
    def direction(self) -> Direction:
        assert self.rule is not None
        return self.rule.direction

    def refuse(self, rank: int, reason: Reason, detail: str, **data: Any) -> Verdict:
        """A refusal in the words of a :class:`MoveRefused`: the mobile named first, the
        pivot (global) in the data."""
        data.setdefault("pivot_joint_global", int(self.j))
        return Verdict.refused(rank, reason, f"{self.mod.id}: {detail}", data)


@dataclass
class _Attempt:
    """A module showing a negative pair at body joint ``pivot_body``."""

    pivot_body: Joint
    opened_ns: int
    done: bool = False  # moved, or superseded: no refusal when it closes
    drive_since: int | None = None
    plan: _Plan | None = None
    best: Verdict | None = None  # the furthest refusal met


@dataclass
class _Flight:
    module: str
    started_ns: int
    plan: _Plan
    from_cell: Cell
    pivot_body: Joint
    participants: tuple[str, ...]
    carried: bool = False


@dataclass
class _Module:
    id: str
    cell: Cell
    orientation: int
    fixed: bool
    joints_open: tuple[bool, ...] = (False,) * 6
    magnets: tuple[int, ...] = (0,) * 6
    attempts: dict[Joint, _Attempt] = field(default_factory=dict)

    def magnet(self, global_side: int) -> int:
        return self.magnets[Side.of(global_side - self.orientation) - 1]

    def body_side(self, global_side: int) -> Side:
        return Side.of(global_side - self.orientation)

    def solenoid_open(self, global_joint: int) -> bool:
        return self.joints_open[Joint.of(global_joint - self.orientation) - 1]


def negative_pairs(magnets: Sequence[int]) -> list[Joint]:
    """Body joints k whose two sides (k-1, k) are both negative (or faulty, so that a
    relay fight on a mobile side is diagnosed rather than ignored)."""
    neg = [m in (MAG_NEG, MAG_BOTH) for m in magnets]
    return [k for k in Joint if neg[Side.of(k - 1) - 1] and neg[k - 1]]


_MAG_VALUES = frozenset((MAG_OFF, MAG_POS, MAG_NEG, MAG_BOTH))
_PAIRS: dict[tuple[int, ...], frozenset[Joint]] = {}  # a module's magnets -> its negative pairs


def _pairs(magnets: tuple[int, ...]) -> frozenset[Joint]:
    """:func:`negative_pairs` as a set, kept per magnet state (at most 4**6 of them)."""
    pairs = _PAIRS.get(magnets)
    if pairs is None:
        pairs = _PAIRS[magnets] = frozenset(negative_pairs(magnets))
    return pairs


_AROUND: dict[Cell, tuple[Cell, ...]] = {}


def _around(cell: Cell) -> tuple[Cell, ...]:
    """The six neighbours of ``cell``, sides 1..6 (kept: the lattice does not change)."""
    cells = _AROUND.get(cell)
    if cells is None:
        cells = _AROUND[cell] = tuple(cell.neighbours())
    return cells


@dataclass(frozen=True)
class _Way:
    """A mobile's rotation about one pivot in one direction: where its substrate would
    be, and Table 4-3's rule, cells that must be empty and goal."""

    direction: Direction
    substrate: Cell
    rule: MoveRule
    sweep: tuple[Cell, ...]
    goal: Cell


_WAYS: dict[tuple[Cell, int], tuple[_Way, _Way]] = {}
_READS: dict[tuple[Cell, int], frozenset[Cell]] = {}


def _ways(cell: Cell, j: Joint) -> tuple[_Way, _Way]:
    """CW then CCW about global joint ``j`` of a mobile in ``cell`` (kept per cell and joint)."""
    ways = _WAYS.get((cell, j))
    if ways is None:
        found = []
        for d in (Direction.CW, Direction.CCW):
            rule = move_rule(j, d)
            sub, sweep, goal = rule.cells(cell)
            assert sub == substrate_cell(cell, j, d)  # Table 4-3 and the vertex geometry agree
            found.append(_Way(d, sub, rule, sweep, goal))
        ways = _WAYS[(cell, j)] = (found[0], found[1])
    return ways


def _reads(cell: Cell, j: Joint) -> frozenset[Cell]:
    """Every cell whose occupant (module, obstacle, reservation) or module state an
    evaluation of a mobile in ``cell`` about global joint ``j`` can read: the cell and its
    neighbours (substrate candidates, latches), the goal and sweep of both directions."""
    reads = _READS.get((cell, j))
    if reads is None:
        ways = _ways(cell, j)
        reads = _READS[(cell, j)] = frozenset((cell, *_around(cell), *ways[0].sweep, ways[0].goal,
                                               *ways[1].sweep, ways[1].goal))
    return reads


# Ranks: how far an evaluation got. A refusal reports the highest-ranked failure seen
# during the attempt (checks run in their own order; a relay fight outranks everything
# but a drive that was actually achieved, because it is a hardware fault).
_R_FIXED, _R_SUPPORT, _R_SUBSTRATE, _R_SUB_MOVING, _R_GOAL, _R_SWEEP, _R_REPEL_OFF, \
    _R_REPEL_WRONG, _R_ATTRACT_OFF, _R_ATTRACT_NEG, _R_LATCH, _R_BOTH, _R_TOO_SHORT, \
    _R_PREEMPTED = range(14)
#: Failures the world, not the module's own actuators, causes: when one of these ends a
#: drive before break-away it is the diagnosis (another module got there first).
_WORLD_REASONS = frozenset({Reason.SUPPORTING_MOVE, Reason.SUBSTRATE_MOVING,
                            Reason.GOAL_OCCUPIED, Reason.SWEEP_OCCUPIED,
                            Reason.MISSING_SUBSTRATE})


class MotionJudge:
    """Turns actuator timelines into moves, refusals and faults (the World's physics).

    Call :meth:`on_actuators` for every actuator change, in non-decreasing sim time
    over all modules, and :meth:`advance` when the clock moves without a change (the
    next instant anything can happen is :meth:`next_deadline`). Both return the
    outcomes that became due, in time order.
    """

    def __init__(self, modules: Iterable[ModuleSpec], obstacles: Iterable[Cell] = (),
                 params: PhysicsParams = PhysicsParams()) -> None:
        self.params = params
        self.obstacles = frozenset(obstacles)
        self._mods: dict[str, _Module] = {}
        self._at: dict[Cell, str] = {}
        for spec in modules:
            if spec.id in self._mods:
                raise ValueError(f"module {spec.id!r} listed twice")
            if spec.cell in self._at or spec.cell in self.obstacles:
                raise ValueError(f"module {spec.id!r}: cell {spec.cell} is not free")
            self._mods[spec.id] = _Module(spec.id, spec.cell, spec.orientation % 6, spec.fixed)
            self._at[spec.cell] = spec.id
        self._flights: dict[str, _Flight] = {}
        self._reserved: dict[Cell, str] = {}  # goal and sweep cells of moves in flight
        self._now = 0
        # Modules with a magnet pair on (an attempt): the only ones to evaluate, in the
        # order of ``_mods`` (outcomes of one instant come out in that order), so the cost
        # of an actuator change does not grow with the fleet.
        self._rank = {m: k for k, m in enumerate(self._mods)}
        self._trying: set[str] = set()
        #: the quick way: deadlines in a heap and only the attempts a change can reach
        #: re-evaluated (plus :meth:`on_actuators`' short way where nothing moves or tries
        #: to). False: the reference long way (every deadline listed and every attempt
        #: evaluated at every change), which gives the same outcomes. Set it before use.
        self.quick = True
        # Quick way's bookkeeping (docs/physics.md, "Cost of a change"):
        self._heap: list[tuple[int, int, str, str, int]] = []  # deadlines; stale ones skipped
        self._dirty: set[str] = set()  # modules whose attempts a change may have reached
        self._near: dict[str, tuple[str, ...]] = {}  # module -> its neighbours' ids (cache)
        self._carriers: dict[str, int] = {}  # module -> uncarried flights its magnets hold up
        self._carrying: dict[str, int] = {}  # substrate -> moves in flight on it

    # --- queries ------------------------------------------------------------------
    @property
    def now_ns(self) -> int:
        return self._now

    def at_rest(self) -> bool:
        """Nothing moves and nobody tries to (no magnet pair on anywhere): :meth:`on_actuators`
        takes its short way for any change that makes no pair and no relay fight."""
        return self.quick and not self._flights and not self._trying

    def cell(self, module: str) -> Cell:
        return self._mods[module].cell

    def orientation(self, module: str) -> int:
        return self._mods[module].orientation

    def is_fixed(self, module: str) -> bool:
        return self._mods[module].fixed

    def occupancy(self) -> dict[Cell, str]:
        """Cell -> module for every module (in flight: its start cell)."""
        return dict(self._at)

    def in_flight(self) -> dict[str, Cell]:
        """Module -> goal cell for every move in progress."""
        return {m: f.plan.goal for m, f in self._flights.items()}

    def latched_neighbours(self, module: str) -> list[dict[str, Any]]:
        """Every latch that currently holds ``module`` to a neighbour."""
        return self._latches(self._mods[module], exempt_vertex=None)

    def next_deadline(self) -> int | None:
        """The next sim time at which an outcome can fall due without an actuator change."""
        if not self.quick:
            times = [t for t, _, _ in self._deadlines()]
            return min(times) if times else None
        heap = self._heap
        while heap and not self._due(heap[0]):
            heapq.heappop(heap)
        return heap[0][0] if heap else None

    # --- input --------------------------------------------------------------------
    def on_actuators(self, module: str, t_ns: int, joints_open: Sequence[bool],
                     magnets: Sequence[int]) -> list[Outcome]:
        """One module's new actuator state (body frame J1..J6, S1..S6) at ``t_ns``."""
        if module not in self._mods:
            raise KeyError(f"unknown module {module!r}")
        if len(joints_open) != 6 or len(magnets) != 6:
            raise ValueError("need six joints and six magnets")
        if not _MAG_VALUES.issuperset(magnets):
            raise ValueError(f"magnet values must be -1, 0, 1 or 2: {list(magnets)}")
        mod = self._mods[module]
        mags = tuple(map(int, magnets))
        if self.quick and not self._flights and not self._trying and t_ns >= self._now:
            # Nothing moves and nobody tries to: a change that makes no magnet pair (and no
            # relay fight) can start nothing, and no other module's verdict depends on it
            # (verdicts are made for attempts only). The long way below ends the same.
            if MAG_BOTH not in mags and not _pairs(mags):
                mod.joints_open = tuple(map(bool, joints_open))
                mod.magnets = mags
                self._now = t_ns
                return []
        out = self.advance(t_ns)
        old_mag = mod.magnets
        mod.joints_open = tuple(map(bool, joints_open))
        mod.magnets = mags
        if MAG_BOTH in mags:
            for s in Side:  # a relay fight is reported the moment it starts
                if mags[s - 1] == MAG_BOTH and old_mag[s - 1] != MAG_BOTH:
                    out.append(Fault(module, t_ns, Reason.BOTH_RELAYS,
                                     f"{module}: both relays of body side {int(s)} on",
                                     {"body_side": int(s)}))
        if not self.quick:
            self._update_attempts(mod, out)
            self._check_carry(out)
            self._evaluate_all(out)
            return out
        if mod.attempts or _pairs(mags):  # else no attempt to open or close
            self._update_attempts(mod, out)
        if module in self._carriers:
            self._check_carry(out, module)
        # This change reaches the verdicts of its own module and of its neighbours only: a
        # verdict reads the state (magnets, solenoids, orientation) of the mobile and of the
        # modules beside it (substrate candidates, latches), nobody else's. Only modules
        # with an attempt have verdicts, and none while they move (their attempts are done).
        dirty, trying, flights = self._dirty, self._trying, self._flights
        if module in trying and module not in flights:
            dirty.add(module)
        near = self._near.get(module)
        for nid in self._neighbours_of(mod) if near is None else near:
            if nid in trying and nid not in flights:
                dirty.add(nid)
        if dirty:
            self._evaluate_all(out)
        return out

    def advance(self, t_ns: int) -> list[Outcome]:
        """Let sim time reach ``t_ns``: break-aways, carries and arrivals that fall due."""
        if t_ns < self._now:
            raise ValueError(f"time went backwards: {t_ns} < {self._now}")
        out: list[Outcome] = []
        if self.quick:
            # The heap holds every deadline (pushed when a drive starts or a move breaks
            # away) and some that lapsed (a drive broke, a move stalled): ``_due`` tells them
            # apart, and the heap's order is the long way's min over (time, kind, key).
            heap = self._heap
            while heap and heap[0][0] <= t_ns:
                d = heapq.heappop(heap)
                if self._due(d):
                    self._now = d[0]
                    self._fall_due(d[1], d[3], d[4], out)
                    self._evaluate_all(out)
        else:
            while True:
                due = [d for d in self._deadlines() if d[0] <= t_ns]
                if not due:
                    break
                when, kind, key = min(due, key=lambda d: (d[0], d[1], d[2]))
                self._now = when
                mid, _, pj = key.partition("/")
                self._fall_due(kind, mid, int(pj or 0), out)
                self._evaluate_all(out)
        self._now = t_ns
        return out

    def _fall_due(self, kind: int, mid: str, pivot_body: int, out: list[Outcome]) -> None:
        if kind == 0:
            self._complete(self._flights[mid], out)
        elif kind == 1:
            f = self._flights[mid]
            f.carried = True
            self._hold(f, -1)
        else:
            self._break_away(self._mods[mid], Joint(pivot_body), out)

    def _due(self, d: tuple[int, int, str, str, int]) -> bool:
        """Is the heap entry ``d`` one of the long way's ``_deadlines()`` now?"""
        when, kind, _, mid, pj = d
        p = self.params
        if kind == 2:
            a = self._mods[mid].attempts.get(pj)  # type: ignore[call-overload]
            return (a is not None and not a.done and a.drive_since is not None
                    and a.drive_since + p.breakaway_ns == when)
        f = self._flights.get(mid)
        if f is None:
            return False
        if kind == 0:
            return f.started_ns + p.rotation_ns == when
        return not f.carried and f.started_ns + p.carry_ns == when

    def relocate(self, module: str, cell: Cell, orientation: int) -> None:
        """Put an externally driven body (a real module) where it was confirmed to be.
        Raises ValueError when the cell is taken or the module is in flight."""
        mod = self._mods[module]
        occupant = self._occupant(cell)
        if occupant is not None and occupant != module:
            raise ValueError(f"{module} cannot be at {cell}: taken by {occupant}")
        if module in self._flights:
            raise ValueError(f"{module} is in flight")
        before = mod.cell
        del self._at[mod.cell]
        mod.cell, mod.orientation = cell, orientation % 6
        self._at[cell] = module
        self._placed(module, (before, cell))

    # --- internals ----------------------------------------------------------------
    def _deadlines(self) -> list[tuple[int, int, str]]:
        """(time, kind, key); kind 0 arrival, 1 carry, 2 break-away (that order at ties:
        an arrival frees cells before anyone else commits to them)."""
        p = self.params
        out = []
        for f in self._flights.values():
            out.append((f.started_ns + p.rotation_ns, 0, f.module))
            if not f.carried:
                out.append((f.started_ns + p.carry_ns, 1, f.module))
        for m in self._attempting():
            for a in m.attempts.values():
                if a.drive_since is not None and not a.done:
                    out.append((a.drive_since + p.breakaway_ns, 2, f"{m.id}/{int(a.pivot_body)}"))
        return out

    def _attempting(self) -> list[_Module]:
        """The modules with an attempt, in the order of ``_mods``."""
        rank = self._rank
        return [self._mods[m] for m in sorted(self._trying, key=rank.__getitem__)]

    def _update_attempts(self, mod: _Module, out: list[Outcome]) -> None:
        pairs = _pairs(mod.magnets)
        for k in list(mod.attempts):
            if k not in pairs:  # the pair went off: the attempt is over
                a = mod.attempts.pop(k)
                if not a.done:
                    out.append(self._refusal(mod, a))
        for k in pairs - set(mod.attempts):
            # a pair appearing while the module is in flight is not a new attempt
            mod.attempts[k] = _Attempt(k, self._now, done=mod.id in self._flights)
        if mod.attempts:
            self._trying.add(mod.id)
        else:
            self._trying.discard(mod.id)

    def _refusal(self, mod: _Module, a: _Attempt) -> MoveRefused:
        if a.best is None:  # never evaluated (opened and closed at the same instant)
            return MoveRefused(mod.id, self._now, Reason.TOO_SHORT,
                               f"{mod.id}: magnet pair at body joint {int(a.pivot_body)} "
                               "on for no time", {"held_ns": 0})
        best = a.best
        assert best.reason is not None
        return MoveRefused(mod.id, self._now, best.reason, best.detail, best.data)

    def _evaluate_all(self, out: list[Outcome]) -> None:
        """Evaluate the open attempts: every one (the long way), or those a change since
        the last call reached (the quick way).

        Why the quick way is the same: an evaluation is a pure function of the world
        around the mobile (the ``_dirty`` marks below list what it reads), and its effect
        on its attempt depends only on its verdict and the attempt's state: a verdict
        equal to the attempt's last one changes nothing (a drive already on stays on with
        the same plan; a refusal finds the drive already off and a ``best`` ranked at
        least as high). An attempt whose world did not change since its last evaluation
        would get its last verdict again, so it is skipped. Evaluations write only their
        own attempt and emit nothing, so their order does not matter."""
        if self.quick:
            dirty, self._dirty = self._dirty, set()
            mods = [self._mods[m] for m in dirty if m in self._trying]
        else:
            self._dirty.clear()
            mods = self._attempting()
        for mod in mods:
            if mod.id in self._flights:
                continue
            for a in mod.attempts.values():
                if a.done:
                    continue
                verdict = self._evaluate(mod, a.pivot_body)
                if verdict.ok:
                    if a.drive_since is None:
                        a.drive_since = self._now
                        heapq.heappush(self._heap, (self._now + self.params.breakaway_ns, 2,
                                                    f"{mod.id}/{int(a.pivot_body)}", mod.id,
                                                    int(a.pivot_body)))
                    a.plan = verdict.plan
                    continue
                if a.drive_since is not None:
                    self._drive_broke(mod, a, verdict)
                self._note(a, verdict)

    # What an evaluation of a mobile at cell c reads, and the marks that keep the quick
    # way exact: the state of modules in c and its six neighbours (magnets: substrate
    # candidates and polarity; solenoids and orientation: latches; in flight or not:
    # substrate still, latches), the flights whose substrate is the mobile, and what
    # blocks its goal and sweep cells (modules, obstacles, reservations): ``_reads``. So an
    # actuator change marks its module and the neighbours (``on_actuators``); a
    # break-away, stall or arrival marks the mobiles that read the mover's start, goal or
    # sweep cells (flight status, occupancy, reservations, orientation) and the substrate
    # by name (its supporting-move check); a relocation those that read either cell.
    def _touch(self, cells: Iterable[Cell], *modules: str) -> None:
        """Mark for evaluation ``modules`` and every module with an open attempt whose
        evaluation may read ``cells`` (its own cell and neighbours, the goal and sweep
        of either direction about its pivot: ``_reads``)."""
        dirty = self._dirty
        dirty.update(modules)
        cells = frozenset(cells)
        for mid in self._trying:
            mod = self._mods[mid]
            for a in mod.attempts.values():
                if not a.done and not _reads(mod.cell, Joint.of(a.pivot_body + mod.orientation)).isdisjoint(cells):
                    dirty.add(mid)
                    break

    def _neighbours_of(self, mod: _Module) -> tuple[str, ...]:
        """The ids of the modules beside ``mod`` (kept until a module beside it moves)."""
        at = self._at
        ids = self._near[mod.id] = tuple(n for c in _around(mod.cell) if (n := at.get(c)) is not None)
        return ids

    def _placed(self, module: str, cells: tuple[Cell, Cell]) -> None:
        """``module`` went from one cell to the other: forget the neighbour lists that
        changed, and mark the mobiles it may concern."""
        at, near = self._at, self._near
        near.pop(module, None)
        for c in cells:
            for n in _around(c):
                nid = at.get(n)
                if nid is not None:
                    near.pop(nid, None)
        self._touch(cells, module)

    def _hold(self, f: _Flight, delta: int) -> None:
        """Count ``f`` among the uncarried flights of its mover and substrate (whose
        actuator changes alone can stall it)."""
        for m in (f.module, f.plan.substrate):
            n = self._carriers.get(m, 0) + delta
            if n:
                self._carriers[m] = n
            else:
                del self._carriers[m]

    def _unsupport(self, f: _Flight) -> None:
        n = self._carrying[f.plan.substrate] - 1
        if n:
            self._carrying[f.plan.substrate] = n
        else:
            del self._carrying[f.plan.substrate]

    def _drive_broke(self, mod: _Module, a: _Attempt, verdict: Verdict) -> None:
        """The drive of ``a`` broke before break-away (``verdict`` says why): a world
        cause is the diagnosis (another module got there first); otherwise, if it had
        lasted at all, the drive was too short."""
        assert a.drive_since is not None and verdict.reason is not None
        held = self._now - a.drive_since
        a.drive_since = None
        if verdict.reason in _WORLD_REASONS:
            self._note(a, replace(verdict, rank=_R_PREEMPTED))
        elif held > 0:
            breakaway = self.params.breakaway_ns
            self._note(a, Verdict.refused(
                _R_TOO_SHORT, Reason.TOO_SHORT,
                f"{mod.id}: drive held {held / 1e6:.1f} ms < break-away "
                f"{breakaway / 1e6:.1f} ms (then {verdict.reason.value})",
                {"held_ns": held, "breakaway_ns": breakaway, "then": verdict.reason.value}))

    @staticmethod
    def _note(a: _Attempt, verdict: Verdict) -> None:
        if a.best is None or verdict.rank > a.best.rank:  # ties keep the first: the clearest moment
            a.best = verdict

    def _occupant(self, cell: Cell) -> str | None:
        """What blocks ``cell``: a module id, ``"obstacle"``, or a reservation."""
        if cell in self._at:
            return self._at[cell]
        if cell in self.obstacles:
            return "obstacle"
        if cell in self._reserved:
            return f"reserved by {self._reserved[cell]} in flight"
        return None

    def _evaluate(self, mod: _Module, pivot_body: Joint) -> Verdict:
        """Is the rotation about ``pivot_body`` driven right now? The checks below, in
        this order: the first that refuses is the verdict; if none does, the drive's move."""
        t = _Trial(mod, pivot_body, Joint.of(pivot_body + mod.orientation))
        for check in _CHECKS:
            verdict = check(self, t)
            if verdict is not None:
                return verdict
        assert t.sub is not None and t.rule is not None and t.goal is not None
        assert t.repel_body is not None and t.attract_body is not None
        return Verdict(_Plan(t.rule, t.sub.id, t.goal, t.sweep, t.repel_body, t.attract_body))

    def _not_fixed(self, t: _Trial) -> Verdict | None:
        if t.mod.fixed:
            return t.refuse(_R_FIXED, Reason.FIXED_MODULE, "the fixed module cannot move")
        return None

    def _no_relay_fight(self, t: _Trial) -> Verdict | None:
        pair = (Side.of(t.pivot_body - 1), Side(int(t.pivot_body)))
        bad = [int(s) for s in pair if t.mod.magnets[s - 1] == MAG_BOTH]
        if bad:
            return t.refuse(_R_BOTH, Reason.BOTH_RELAYS,
                            f"both relays on at body side(s) {bad}", body_sides=bad)
        return None

    def _not_a_substrate(self, t: _Trial) -> Verdict | None:
        if self.quick and t.mod.id not in self._carrying:
            return None  # the quick way counts the moves on each substrate
        for f in self._flights.values():
            if f.plan.substrate == t.mod.id:
                return t.refuse(_R_SUPPORT, Reason.SUPPORTING_MOVE,
                                f"is the substrate of {f.module}'s move in flight", mover=f.module)
        return None

    def _substrate_found(self, t: _Trial) -> Verdict | None:
        """One of the two cells touching the pivot vertex holds the substrate; where both
        do, the one repelling the mobile is meant (Hexmove's rule: the repelling side
        decides the direction), and the goal is then taken. Sets the substrate, the rule,
        its goal and sweep."""
        mod, j = t.mod, t.j
        ways = _ways(mod.cell, j)
        candidates: list[tuple[Direction, _Module]] = []
        for w in ways:
            occ = self._at.get(w.substrate)
            if occ is not None:
                candidates.append((w.direction, self._mods[occ]))
        if not candidates:
            cells = [str(w.substrate) for w in ways]
            return t.refuse(_R_SUBSTRATE, Reason.MISSING_SUBSTRATE,
                            f"no module touches pivot joint {int(j)} (cells {', '.join(cells)})",
                            cells=cells)
        if len(candidates) == 2:
            def repels(dm: tuple[Direction, _Module]) -> bool:
                d, s = dm
                facing = (j if d is Direction.CW else j - 1) + 3
                return s.magnet(facing) == MAG_NEG
            repelling = [dm for dm in candidates if repels(dm)]
            if len(repelling) != 1:  # no way to tell which is meant: either way no goal
                both = ", ".join(f"{s.id} at {s.cell}" for _, s in candidates)
                return t.refuse(_R_GOAL, Reason.GOAL_OCCUPIED,
                                f"both cells touching pivot joint {int(j)} are taken ({both}): "
                                "no free goal", by=[s.id for _, s in candidates])
            candidates = repelling
        direction, t.sub = candidates[0]
        w = ways[0] if direction is Direction.CW else ways[1]
        t.rule, t.sweep, t.goal = w.rule, w.sweep, w.goal
        return None

    def _substrate_still(self, t: _Trial) -> Verdict | None:
        assert t.sub is not None
        if t.sub.id in self._flights:
            return t.refuse(_R_SUB_MOVING, Reason.SUBSTRATE_MOVING,
                            f"substrate {t.sub.id} is itself moving", substrate=t.sub.id)
        return None

    def _goal_free(self, t: _Trial) -> Verdict | None:
        assert t.goal is not None
        blocker = self._occupant(t.goal)
        if blocker is not None:
            return t.refuse(_R_GOAL, Reason.GOAL_OCCUPIED,
                            f"goal {t.goal} of {t.direction.value} about joint {int(t.j)} is "
                            f"taken ({blocker})", goal=[t.goal.x, t.goal.y], by=blocker)
        return None

    def _sweep_free(self, t: _Trial) -> Verdict | None:
        blocked = [(c, b) for c in t.sweep if (b := self._occupant(c)) is not None]
        if blocked:
            txt = ", ".join(f"{c} ({b})" for c, b in blocked)
            return t.refuse(_R_SWEEP, Reason.SWEEP_OCCUPIED,
                            f"sweep of {t.direction.value} about joint {int(t.j)} blocked: {txt}",
                            cells=[[c.x, c.y] for c, _ in blocked], by=[b for _, b in blocked])
        return None

    def _substrate_polarity(self, t: _Trial) -> Verdict | None:
        """The substrate's side facing the mobile repels (negative), its other side at the
        pivot attracts (positive). Sets those two body sides."""
        sub, j, cw = t.sub, t.j, t.direction is Direction.CW
        assert sub is not None
        toward = j if cw else j - 1  # mobile's global side to sub
        repel_g = Side.of(toward + 3)
        attract_g = Side.of(j + 4) if cw else Side.of(j + 1)
        repel_b, attract_b = t.repel_body, t.attract_body = (sub.body_side(repel_g),
                                                             sub.body_side(attract_g))
        rv, av = sub.magnet(repel_g), sub.magnet(attract_g)
        if rv == MAG_NEG and av == MAG_POS:
            return None
        pol = {"substrate": sub.id, "repel_body_side": int(repel_b),
               "attract_body_side": int(attract_b), "repel": rv, "attract": av}
        if MAG_BOTH in (rv, av):
            return t.refuse(_R_BOTH, Reason.BOTH_RELAYS,
                            f"substrate {sub.id} has both relays on at a pivot side", **pol)
        if rv != MAG_NEG:
            return t.refuse(_R_REPEL_OFF if rv == MAG_OFF else _R_REPEL_WRONG,
                            Reason.WRONG_POLARITY,
                            f"substrate {sub.id} body side {int(repel_b)} facing the mobile is "
                            f"{_pol(rv)}, needs negative (repulsion)", **pol)
        if av != MAG_POS:
            return t.refuse(_R_ATTRACT_OFF if av == MAG_OFF else _R_ATTRACT_NEG,
                            Reason.WRONG_POLARITY if av == MAG_OFF else Reason.NO_ATTRACTION,
                            f"substrate {sub.id} body side {int(attract_b)} is {_pol(av)}, "
                            "needs positive (attraction)"
                            + (" -- both substrate sides negative (SCCW defect?)"
                               if av == MAG_NEG else ""), **pol)
        return None

    def _latches_released(self, t: _Trial) -> Verdict | None:
        assert t.sub is not None
        latched = self._latches(t.mod, exempt_vertex=(t.sub.id, t.j))
        if latched:
            txt = "; ".join(f"{x['neighbour']} at global joint {x['vertex']} "
                            f"({x['owner']}'s solenoid J{x['owner_joint']} closed)"
                            for x in latched)
            return t.refuse(_R_LATCH, Reason.NEIGHBOUR_LATCHED, f"still latched: {txt}",
                            latches=latched)
        return None

    def _latches(self, mod: _Module, exempt_vertex: tuple[str, Joint] | None
                 ) -> list[dict[str, Any]]:
        """Latches holding ``mod`` to its neighbours. Each shared edge (mod's global side
        s) has mod's pin at mod's vertex s+1 and the neighbour's pin at mod's vertex s."""
        found = []
        at, flights = self._at, self._flights
        for (mine, mine_vertex, theirs, their_vertex), c in zip(_PINS, _around(mod.cell)):
            nid = at.get(c)
            if nid is None or nid in flights:  # a module in flight is swinging away
                continue
            n = self._mods[nid]
            # (owner, owner's global joint, vertex of mod)
            for owner, owner_joint_g, vertex in ((mod, mine, mine_vertex), (n, theirs, their_vertex)):
                if exempt_vertex == (nid, vertex):
                    continue  # the hinge on the rotation axis
                if not owner.solenoid_open(owner_joint_g):
                    found.append({"neighbour": nid, "vertex": int(vertex), "owner": owner.id,
                                  "owner_joint": int(Joint.of(owner_joint_g - owner.orientation))})
        return found

    def _break_away(self, mod: _Module, pivot_body: Joint, out: list[Outcome]) -> None:
        a = mod.attempts[pivot_body]
        if self.quick and a.plan is not None and mod.id not in self._dirty:
            # The drive is on (its last verdict was this plan) and nothing it reads changed
            # since (every change is evaluated at once): the verdict now is that plan.
            plan: _Plan | None = a.plan
        else:
            verdict = self._evaluate(mod, pivot_body)
            plan = verdict.plan
        if plan is None:  # cannot happen: every change re-evaluates; be safe
            a.drive_since = None
            a.plan = None
            self._note(a, verdict)
            return
        started = a.drive_since
        assert started is not None
        for other in mod.attempts.values():
            other.done = True
            other.drive_since = None
        participants = (mod.id, plan.substrate) + tuple(sorted(
            nid for c in mod.cell.neighbours()
            if (nid := self._at.get(c)) is not None and nid != plan.substrate))
        f = self._flights[mod.id] = _Flight(mod.id, started, plan, mod.cell, pivot_body, participants)
        for c in (plan.goal, *plan.sweep):
            self._reserved[c] = mod.id
        p = self.params
        heapq.heappush(self._heap, (started + p.rotation_ns, 0, mod.id, mod.id, 0))
        heapq.heappush(self._heap, (started + p.carry_ns, 1, mod.id, mod.id, 0))
        self._hold(f, 1)
        self._carrying[plan.substrate] = self._carrying.get(plan.substrate, 0) + 1
        self._touch((mod.cell, plan.goal, *plan.sweep), plan.substrate)
        out.append(MoveStarted(mod.id, self._now, started, mod.cell, plan.goal,
                               plan.rule.joint, plan.rule.direction, plan.substrate))

    def _carry_ok(self, f: _Flight) -> bool:
        mod, sub = self._mods[f.module], self._mods[f.plan.substrate]
        pair = (Side.of(f.pivot_body - 1), Side(int(f.pivot_body)))
        return (all(mod.magnets[s - 1] == MAG_NEG for s in pair)
                and sub.magnets[f.plan.attract_body - 1] == MAG_POS)

    def _check_carry(self, out: list[Outcome], changed: str | None = None) -> None:
        """Stall the moves whose attraction stopped before half-way: every uncarried one
        (the long way), or those ``changed``'s magnets hold up (the quick way: a carry
        reads the mover's and the substrate's magnets only, and held at break-away)."""
        for f in list(self._flights.values()):
            if f.carried or (changed is not None and changed not in (f.module, f.plan.substrate)):
                continue
            if self._carry_ok(f):
                continue
            # the pull stopped before half-way: the module falls back to its cell
            held = self._now - f.started_ns
            del self._flights[f.module]
            self._release(f.module)
            self._hold(f, -1)
            self._unsupport(f)
            self._touch((f.from_cell, f.plan.goal, *f.plan.sweep), f.plan.substrate)
            out.append(Fault(f.module, self._now, Reason.STALLED,
                             f"{f.module}: attraction stopped {held / 1e6:.1f} ms into the "
                             f"rotation (< {self.params.carry_ns / 1e6:.1f} ms): stalled, fell "
                             f"back to {f.from_cell}",
                             {"from": [f.from_cell.x, f.from_cell.y],
                              "to": [f.plan.goal.x, f.plan.goal.y], "held_ns": held}))

    def _release(self, module: str) -> None:
        for c in [c for c, m in self._reserved.items() if m == module]:
            del self._reserved[c]

    def _complete(self, f: _Flight, out: list[Outcome]) -> None:
        mod = self._mods[f.module]
        del self._flights[f.module]
        self._release(f.module)
        if not f.carried:  # carry_ns == rotation_ns: the arrival came first
            self._hold(f, -1)
        self._unsupport(f)
        before = mod.orientation
        del self._at[mod.cell]
        assert f.plan.goal not in self._at  # reserved since break-away
        mod.cell = f.plan.goal
        self._at[mod.cell] = mod.id
        mod.orientation = orientation_after(before, f.plan.rule.direction)
        self._placed(mod.id, (f.from_cell, mod.cell))
        self._touch(f.plan.sweep, f.plan.substrate)
        out.append(MoveCompleted(mod.id, self._now, f.started_ns, f.from_cell, mod.cell,
                                 f.plan.rule.joint, f.plan.rule.direction, before,
                                 mod.orientation, f.plan.substrate, f.participants))


#: :meth:`MotionJudge._evaluate`'s checks, in their order
_CHECKS = (
    MotionJudge._not_fixed,            # the fixed module never moves
    MotionJudge._no_relay_fight,       # the mobile's pair: no side with both relays on
    MotionJudge._not_a_substrate,      # nobody's move in flight pivots on the mobile
    MotionJudge._substrate_found,      # a module touches the pivot (the repelling one of two)
    MotionJudge._substrate_still,      # ... and is not itself moving
    MotionJudge._goal_free,            # Table 4-3's goal cell: no module, obstacle, reservation
    MotionJudge._sweep_free,           # ... and its sweep cells
    MotionJudge._substrate_polarity,   # the substrate repels the mobile and attracts it to the goal
    MotionJudge._latches_released,     # every latch open but the hinge at the pivot
)
#: per global side s of a mobile: its own pin on that edge and the vertex it holds, the
#: neighbour's pin (global joint) and its vertex (``_latches``)
_PINS = tuple((latch_joint(s), Joint.of(s + 1), latch_joint(s + 3), Joint.of(s)) for s in Side)


def _pol(v: int) -> str:
    return {MAG_OFF: "off", MAG_POS: "positive", MAG_NEG: "negative", MAG_BOTH: "both"}[v]

"""Problems, plans and the plan validator.

A :class:`Plan` is a list of time steps; each step is a list of :class:`Move` executed
at the same time (one move per step for serial planners). :func:`validate` replays a
plan from the initial configuration through the one legality rule
(:func:`planner_svc.planners.rules.move_violation`) and raises :class:`PlanError` at the first
illegal move.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

from bus.errors import HexbenchError
from bus.lattice import Cell

from .rules import Coord, Move, apply_step, is_connected, move_violation, xy

#: Energy of one move (thesis §4.4.2, spec §8): 4 magnets, 8 solenoids, drive and logic
#: for about 100 ms = 227 W x 0.1 s. An estimate: the thesis calls it the maximum per move.
JOULES_PER_MOVE = 22.7


class PlanError(HexbenchError, ValueError):
    """A plan that breaks the move rule or does not do what it claims."""


@dataclass(frozen=True)
class Problem:
    """A reconfiguration problem: where the modules are, where they must be."""

    initial: frozenset[Cell]
    goal: frozenset[Cell]
    fixed: Cell
    obstacles: frozenset[Cell] = frozenset()
    name: str = "problem"

    @classmethod
    def of(cls, initial: Iterable[Cell | Coord], goal: Iterable[Cell | Coord],
           fixed: Cell | Coord, obstacles: Iterable[Cell | Coord] = (),
           name: str = "problem") -> "Problem":
        """Build and check a problem (same fleet size, fixed module in both, connected start)."""
        p = cls(frozenset(Cell(*xy(c)) for c in initial), frozenset(Cell(*xy(c)) for c in goal),
                Cell(*xy(fixed)), frozenset(Cell(*xy(c)) for c in obstacles), name)
        if len(p.initial) != len(p.goal):
            raise PlanError(f"{name}: {len(p.initial)} modules but {len(p.goal)} goal cells")
        if p.fixed not in p.initial or p.fixed not in p.goal:
            raise PlanError(f"{name}: the fixed module {p.fixed} must be in the initial and the goal "
                            "configuration")
        if (p.initial | p.goal) & p.obstacles:
            raise PlanError(f"{name}: obstacles overlap modules or goal cells")
        if not is_connected({xy(c) for c in p.initial}):
            raise PlanError(f"{name}: the initial configuration is not connected")
        return p

    @classmethod
    def from_scenario(cls, scenario) -> "Problem":  # bus.scenario.Scenario
        """The problem of a :class:`bus.scenario.Scenario`."""
        return cls.of(scenario.initial, scenario.goal, scenario.fixed, scenario.obstacles,
                      scenario.name)


@dataclass
class Plan:
    """The result of a planner run.

    ``ok`` is True when the last step reaches the goal; otherwise ``reason`` says why
    the planner stopped (a stall, a proof of unreachability, a search limit) and
    ``steps`` hold the legal moves made before that.
    """

    planner: str
    problem: Problem
    steps: list[list[Move]] = field(default_factory=list)
    ok: bool = False
    reason: str = ""
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)

    @property
    def moves(self) -> int:
        return sum(len(s) for s in self.steps)

    @property
    def energy_joules(self) -> float:
        """Estimated actuation energy: :data:`JOULES_PER_MOVE` per move."""
        return self.moves * JOULES_PER_MOVE

    def configurations(self) -> list[frozenset[Cell]]:
        """The configuration before the first step and after each step."""
        occ = {xy(c) for c in self.problem.initial}
        out = [frozenset(Cell(*c) for c in occ)]
        for step in self.steps:
            occ = apply_step(occ, step)
            out.append(frozenset(Cell(*c) for c in occ))
        return out

    def summary(self) -> str:
        status = "goal reached" if self.ok else f"FAILED: {self.reason}"
        return (f"{self.planner} on {self.problem.name}: {status}; steps {len(self.steps)}, "
                f"moves {self.moves}, planning {self.seconds * 1000:.1f} ms, "
                f"energy {self.energy_joules:.1f} J (estimate, {JOULES_PER_MOVE} J/move)")


def check_reach(plan: Plan, reach) -> None:  # reach: bus.scenario.Reach
    """Raise :class:`PlanError` at the first move to a cell the protocol cannot name relative
    to the reference (a module there could not be told its cell, nor report it)."""
    for n, step in enumerate(plan.steps, 1):
        for mv in step:
            if why := reach.beyond(mv.goal):
                raise PlanError(f"the plan leaves what the protocol can name at step {n}, "
                                f"{mv.mobile} -> {mv.goal}: {why}")


def validate(plan: Plan | Sequence[Sequence[Move]], initial: Iterable[Cell | Coord] | None = None,
             goal: Iterable[Cell | Coord] | None = None, fixed: Cell | Coord | None = None,
             obstacles: Iterable[Cell | Coord] = ()) -> frozenset[Cell]:
    """Replay a plan and return the final configuration.

    Raises :class:`PlanError` at the first illegal move, naming the step, the move and
    the broken condition; and when a plan that claims success (``Plan.ok`` or an
    explicit ``goal``) does not end in the goal. ``initial``/``goal``/``fixed`` default
    to the plan's problem.
    """
    if isinstance(plan, Plan):
        p = plan.problem
        initial = p.initial if initial is None else initial
        goal = p.goal if goal is None and plan.ok else goal
        fixed = p.fixed if fixed is None else fixed
        obstacles = obstacles or p.obstacles
        steps: Sequence[Sequence[Move]] = plan.steps
    else:
        steps = plan
    if initial is None or fixed is None:
        raise PlanError("validate needs the initial configuration and the fixed cell")
    occ = {xy(c) for c in initial}
    if not is_connected(occ):
        raise PlanError("the initial configuration is not connected")
    for n, step in enumerate(steps, 1):
        if not step:
            raise PlanError(f"step {n} has no move")
        for k, mv in enumerate(step):
            others = [o for i, o in enumerate(step) if i != k]
            why = move_violation(occ, mv, fixed, obstacles, others)
            if why:
                raise PlanError(f"step {n}, move {mv.describe()}: {why}")
        occ = apply_step(occ, step)
    final = frozenset(Cell(*c) for c in occ)
    if goal is not None:
        want = {Cell(*xy(c)) for c in goal}
        if final != want:
            missing = ", ".join(map(str, sorted(want - final)))
            extra = ", ".join(map(str, sorted(final - want)))
            raise PlanError(f"the plan ends {len(final - want)} module(s) off the goal: "
                            f"goal cells empty: {missing}; modules outside the goal: {extra}")
    return final

"""The planner service: the PC on the bus, from power-up to the goal.

It only talks to the bus (principle 1): a :class:`PcEndpoint` on the centre channel,
plus the world's published ground truth when a virtual fleet is present. Layers:
bring-up (:mod:`planner_svc.bringup`), planning (:mod:`planner_svc.planners`),
actuation and verification (:mod:`planner_svc.executor`). Progress goes to stdout and
to ``planner/progress``; the planner's view of each step to ``planner/state`` (replay
overlays). ``script:<file>`` planners run a script (:mod:`planner_svc.script`) instead.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

from bus.lattice import Cell
from bus.messages import PlannerProgress, PlannerState
from bus.scenario import Scenario
from bus.timing import NS_PER_S
from bus.transport import Bus

from . import planners
from .planners import thesis
from .bringup import BringUp, BringUpError, Fleetview
from .endpoint import PcEndpoint
from .executor import THESIS_TIMING, Executor, GroundTruth, MoveFailed, PortWatch
from .planners.plan import Plan, PlanError, Problem, check_reach, validate
from .planners.rules import Move
from .script import ScriptError, run_script

#: Rounds a Walter run beats past the round model's last before it gives up.
ROUND_LIMIT_SLACK = 5


@dataclass
class RunResult:
    """How a run ended: ``ok`` when the goal is reached; ``reason`` otherwise."""

    ok: bool
    reason: str = ""
    planner: str = ""
    steps: int = 0
    moves: int = 0
    planned_moves: int = 0
    planning_s: float = 0.0
    sim_s: float = 0.0
    wall_s: float = 0.0
    energy_j: float = 0.0
    energy_estimate_j: float = 0.0
    localize_steps: int = 0
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        status = (self.reason or "goal reached") if self.ok else f"FAILED: {self.reason}"
        return (f"{self.planner}: {status}; steps {self.steps}, moves {self.moves}"
                f" (planned {self.planned_moves}), planning {self.planning_s * 1000:.1f} ms, "
                f"run {self.sim_s:.1f} s sim / {self.wall_s:.1f} s wall, energy "
                f"{self.energy_j:.1f} J measured by the world"
                f" ({self.energy_estimate_j:.1f} J estimated)")


class PlannerService:
    """Bring up, plan, actuate and verify one scenario through the bus."""

    def __init__(self, bus: Bus, scenario: Scenario, planner: str, *,
                 timing: tuple[int, int, int] = THESIS_TIMING,
                 say: Callable[[str], None] = print, plan: Plan | None = None) -> None:
        """``plan``: made from the scenario before the fleet booted (``hexbench run`` checks it
        then); used when the localized configuration is the scenario's."""
        self.bus = bus
        self.early_plan = plan
        self.scenario = scenario
        self.planner_name = planner
        self.say = say
        self.pc = PcEndpoint(bus, baud=scenario.ir_baud)
        self.truth = GroundTruth(bus)
        self.bringup = BringUp(self.pc, scenario, say=say)
        # real modules answer through serial bridges, whose ports may go and come back
        real = any(m.kind != "virtual" for m in scenario.modules)
        self.ports = PortWatch(bus) if real else None
        self.timing = timing
        self.view: Fleetview | None = None
        self._planned = 0  # moves in the plan, once there is one
        self._moves_began: float | None = None  # wall time the first move began

    # -- progress out --------------------------------------------------------------------------
    def _progress(self, step: int, moves: int, message: str, *, done: bool = False,
                  ok: bool = True) -> None:
        goal = set(self.scenario.goal)
        # the PC's belief; a script keeps none, so the world's cells where it has one
        cells = set(self.view.cells()) if self.view else self.truth.cells()
        filled = len(goal & cells)
        self.bus.put(self.bus.keys.planner("progress"), PlannerProgress(
            self.bus.clock.now_ns(), step, moves, filled, len(goal), message, done, ok,
            planned=self._planned).to_json())
        t = (self.bus.clock.now_ns() - self.bus.clock.started_ns) / NS_PER_S
        of = f"/{self._planned}" if self._planned else ""
        # the last line names the outcome only: the caller prints the run's summary once
        self.say(f"[{t:8.2f} s] {planners.progress_unit(self.planner_name)} {step:3} moves {moves:3}{of} "
                 f"goal {filled}/{len(goal)}  {message.split('; ')[0] if done else message}"
                 + ("" if done else self._time_left(moves)))

    def _time_left(self, moves: int) -> str:
        """``  (~12 s left)``: the wall time the remaining moves take at this run's pace so far."""
        if not self._planned or not moves or self._moves_began is None or moves >= self._planned:
            return ""
        left = (time.monotonic() - self._moves_began) / moves * (self._planned - moves)
        return f"  (~{left:.0f} s left)" if left >= 1 else ""  # a fast virtual run: no noise

    def _state(self, step: int, moves: list[Move]) -> None:
        occ = set(self.view.cells()) if self.view else set()
        goal = set(self.scenario.goal)
        electrons, voids = thesis.electrons_and_voids(occ, goal)
        mobile = thesis.mobile_electrons(electrons, occ)
        pv = thesis.potential_voids(voids, occ, mobile)
        xy = lambda cs: [[c.x, c.y] for c in sorted(cs)]  # noqa: E731
        values: dict[Cell, float] = {}
        if moves and len(occ) <= 200:  # the value function of the first pair (thesis layer 4)
            try:
                _, vf = thesis.next_location(occ, goal, moves[0].mobile, moves[0].goal,
                                             self.scenario.obstacles)
                values = dict(vf.values)
            except (ValueError, KeyError):
                values = {}
        self.bus.put(self.bus.keys.planner("state"), PlannerState(
            self.bus.clock.now_ns(), step, self.planner_name, xy(occ), xy(goal), xy(electrons),
            xy(voids), xy(mobile), xy(pv), [[[m.mobile.x, m.mobile.y], [m.goal.x, m.goal.y]]
                                            for m in moves],
            xy(values), [values[c] for c in sorted(values)]).to_json())

    # -- the run -------------------------------------------------------------------------------
    def run(self, since_ns: int = 0) -> RunResult:
        t_wall = time.perf_counter()
        result = RunResult(False, planner=self.planner_name)
        try:
            self._run(result, since_ns)
        except (BringUpError, MoveFailed, PlanError, ScriptError) as exc:
            result.ok = False
            result.reason = str(exc)
        result.sim_s = (self.bus.clock.now_ns() - self.bus.clock.started_ns) / NS_PER_S
        result.wall_s = time.perf_counter() - t_wall
        result.energy_j = self.truth.energy_j
        result.localize_steps = self.bringup.localize_steps
        self._progress(result.steps, result.moves, result.summary(), done=True, ok=result.ok)
        return result

    def _run(self, result: RunResult, since_ns: int) -> None:
        if self.planner_name.startswith(planners.SCRIPT_PREFIX):
            self.bringup.wait_boot(since_ns)
            run_script(self.planner_name[len(planners.SCRIPT_PREFIX):], self.pc, self.bringup,
                       say=self.say)
            result.ok, result.reason = True, "script finished"
            if self.truth.present:
                truth = self.truth.cells()
                at_goal = truth == set(self.scenario.goal)
                result.reason += "; the world is " + ("at the goal" if at_goal else "not at the goal")
            return
        if self.planner_name == planners.WALTER:
            self._run_walter(result, since_ns)
            return
        planner = planners.get(self.planner_name)
        self.view = self.bringup.run(since_ns)
        if self.scenario.profile == "thesis-2009":
            raise BringUpError("thesis-2009 modules have no addressing: every module executes "
                               "every frame and Ref makes every listener a reference, so a "
                               "planner cannot drive one move at a time; use the v2 profile, or "
                               "a script:<file> planner (the thesis's own way, one frame at a time)")
        initial = self.view.cells()
        if initial != frozenset(self.scenario.initial):
            self.say("note: the localized configuration differs from the scenario's: "
                     f"{sorted(map(str, initial ^ frozenset(self.scenario.initial)))}")
        problem = Problem.of(initial, self.scenario.goal, self.scenario.fixed,
                             self.scenario.obstacles, self.scenario.name)
        self.say(f"planning: {self.planner_name} on {len(initial)} modules ...")
        early = self.early_plan
        plan: Plan = early if early is not None and early.problem == problem else planner.plan(problem)
        validate(plan)
        check_reach(plan, self.scenario.reach)
        result.planning_s, result.planned_moves = plan.seconds, plan.moves
        result.energy_estimate_j = plan.energy_joules
        result.notes = list(plan.notes)
        self.say(f"plan: {plan.summary()}")
        self._planned, self._moves_began = plan.moves, time.monotonic()
        executor = Executor(self.pc, self.view, self.bringup, self.truth, timing=self.timing,
                            say=self.say, ports=self.ports)
        for n, step in enumerate(plan.steps, 1):
            self._state(n, step)
            for mv in step:
                executor.execute(mv)
                result.moves = executor.moves_done
                self._progress(n, result.moves, f"moved {mv}")
            result.steps = n
        if not plan.ok:
            raise PlanError(f"planner {self.planner_name} stopped: {plan.reason}")
        if self.view.cells() != frozenset(self.scenario.goal):
            raise MoveFailed("the moves were made but the belief is not the goal")
        if self.truth.present:
            truth = self.truth.cells()
            if truth != set(self.scenario.goal):
                raise MoveFailed(f"the world does not match the goal: "
                                 f"{sorted(map(str, truth ^ set(self.scenario.goal)))}")
        self._state(result.steps + 1, [])
        result.ok, result.reason = True, "goal reached"

    # -- the distributed planner -----------------------------------------------------------------
    def _run_walter(self, result: RunResult, since_ns: int) -> None:
        """Walter, Tsai & Amato (docs/protocol.md, docs/planner.md): bring-up, the goal checked
        and the substrate path chosen, the problem uploaded, one beat a round until every
        module reports its goal reached (or the round limit), then the world's verdict. The
        fleet is held to the round model round by round."""
        from .planners.walter import Inadmissible, choose
        from .rounds import RoundDriver, beyond_the_modules, problem_of

        too_many = beyond_the_modules(len(self.scenario.modules))
        if too_many:  # before bring-up (hexbench run refuses it before the fleet boots)
            raise PlanError(f"walter: {too_many}")
        view = self.bringup.run(since_ns)
        if self.scenario.profile == "thesis-2009":
            raise BringUpError("thesis-2009 modules have no Walter rounds: use the v2 profile")
        initial = sorted(view.cells())
        try:
            choice = choose(self.scenario.goal, initial)
        except Inadmissible as exc:
            raise PlanError(f"walter: {exc}") from None
        if choice.chain[-1] != self.scenario.fixed:
            raise PlanError(f"walter: the fixed module is at {self.scenario.fixed}, not where I "
                            f"meets G ({choice.chain[-1]}): the anchor must be the reference")
        model = choice.model()
        model.run()
        expected = {r.number: sorted((mv.module, mv.direction.value, (mv.to_cell.x, mv.to_cell.y))
                                     for mv in r.moves) for r in model.rounds}
        self.say(f"walter: {choice.summary()}")
        self._planned = sum(len(m) for m in expected.values())
        result.planned_moves = self._planned
        position = {c: i for i, c in enumerate(choice.chain)}
        ident = {m.id: position[m.cell] for m in view.modules.values() if m.cell in position}
        driver = RoundDriver(self.pc, self.scenario, say=self.say)
        driver.upload(problem_of(choice, model))
        seen = len(self.truth.events)
        self._moves_began = time.monotonic()

        def each_round(r: int, heard: int) -> None:
            nonlocal seen
            events = self.truth.events[seen:]
            seen = len(self.truth.events)
            bad = [e for e in events if e.kind in ("move-refused", "fault")]
            moved = sorted((ident.get(int(e.module[1:]), -1), e.data["direction"], tuple(e.data["to"]))
                           for e in events if e.kind == "move-completed")
            result.moves += len(moved)
            result.steps = r
            self._progress(r, result.moves, f"round {r}: {len(moved)} moved, "
                           + ("still on their way" if heard else "every module in its goal"))
            if bad:
                e = bad[0]
                raise MoveFailed(f"round {r}: {e.module} {e.kind} {e.reason}: "
                                 f"{e.data.get('detail', '')}", None, None, e.reason)
            if moved != expected.get(r, []):
                name = {p: f"m{i}" for i, p in ident.items()}
                said = [f"{name.get(p, '?')} did not move {d} to {c}" for p, d, c in expected.get(r, [])
                        if (p, d, c) not in moved]
                said += [f"{name.get(p, '?')} moved {d} to {c}" for p, d, c in moved
                         if (p, d, c) not in expected.get(r, [])]
                raise MoveFailed(f"round {r}: {'; '.join(said)}, unlike the round model", None, None,
                                 "diverged")

        try:
            rounds = driver.run(len(model.rounds) + ROUND_LIMIT_SLACK, progress=each_round)
        finally:
            driver.stop()
        if not rounds.done:
            raise MoveFailed(f"walter: modules still on their way after {rounds.rounds} rounds")
        truth = self.truth.cells()
        if self.truth.present and truth != set(self.scenario.goal):
            raise MoveFailed(f"the world does not match the goal: "
                             f"{sorted(map(str, truth ^ set(self.scenario.goal)))}")
        result.ok, result.reason = True, f"goal reached in {rounds.rounds} rounds"

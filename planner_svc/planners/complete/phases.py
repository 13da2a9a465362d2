"""The order of ``complete``'s phases (:func:`plan_complete`): which run, on which
fleets, which plan is kept, and the notes that say where it comes from. See
:mod:`planner_svc.planners.complete` for the whole story, and docs/planner.md, *Measured
for what was kept*, for what the thresholds here gave when they were measured."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..bounds import assignment_lower_bound
from ..descent import descend
from ..plan import Plan, Problem
from ..rules import Coord, Move, neighbours_xy, xy
from ..exact import DEFAULT_MARGIN, fewer_moves, search_from
from ..shorten import shorten
from .digging import HOLE_CALLS
from .relays import Heuristic
from .smoothing import smoothed_plan
from .steps import play, reverse_steps
from .walks import AssignWalk, FrontWalk

#: Fleets up to this size fall back to the exact search when the heuristic is stuck.
EXACT_LIMIT = 10
#: Configurations the exact fallback may expand.
EXACT_BUDGET = 200_000
#: Fleets up to this size also look for a plan with fewer moves by the exact search, of at
#: most FEWEST_BUDGET configurations (thesis-12: 19 moves become 18, in 1720).
FEWEST_LIMIT = 12
FEWEST_BUDGET = 2500
#: Large fleets descend the bound first (:mod:`planner_svc.planners.descent`) when it is at most
#: this many moves per electron.
DESCENT_REACH = 4
#: Where the descent and the relays are both stuck, digging on from where the descent
#: stopped is kept at once if, shortened, it is at most this many times the bound: below
#: it the last resort's other tries seldom beat it, above it they often do.
DUG_KEEP = 3.5
#: Where the descent's relays are stuck, digging on from where the descent stopped (at
#: most DUG_EARLY_CALLS digs) is kept before any other relays run if, shortened, it is
#: at most this many times the bound: a few digs are quick, and where they give a plan
#: that short the relays from the start mostly get stuck and come to the same digs later;
#: longer ones are left to those relays, which are then often shorter.
DUG_EARLY = 2.5
DUG_EARLY_CALLS = 5
#: Digs on the smoothed shapes of fleets over SMOOTH_LIMIT modules (the last resort there).
HOLE_CALLS_LARGE = 100
#: On those fleets, relays stopped with more than this many voids left have walled voids
#: in: only digging is tried, through smoothed shapes first. With this many or fewer the
#: other relay runs go first, then digging both ways (the shorter plan is kept).
FEW_VOIDS = 4
#: Fleets over this size are large: their relays advance
#: (:meth:`.relays.Heuristic._advance_step`), they descend the bound first where it is
#: local, and their last resort digs up to HOLE_CALLS_LARGE times (on smaller fleets the
#: smoothed shapes, :mod:`.smoothing`, do better than advances).
SMOOTH_LIMIT = 300
#: Fleets up to this size also try the relay heuristic when phase 1 succeeds, keeping
#: the shorter plan.
COMPARE_LIMIT = 30

#: Mean number of occupied neighbours per goal cell from which a goal counts as compact
#: (a tree has less than two; hex-convex shapes have five or more).
COMPACT_DEGREE = 3.0


def plan_complete(plan: Plan, exact_limit: int = EXACT_LIMIT) -> None:
    """Fill ``plan`` (serial, one move per step); see the module docstring.

    The phases (:func:`_plan_phases`) run in turn until one keeps a plan. The plan kept is
    then shortened (:mod:`planner_svc.planners.shorten`, stretches re-planned in windows
    too), unless it is made of lone walks only (:attr:`Kept.lone_walks`). On fleets of
    :data:`FEWEST_LIMIT` modules or fewer, the exact search then looks for a plan with
    fewer moves (:func:`planner_svc.planners.exact.fewer_moves`, at most
    :data:`FEWEST_BUDGET` configurations) and takes it if there is one.
    """
    kept = _plan_phases(plan, exact_limit)
    if not kept.lone_walks:
        shorten(plan, windows=True)
    small = len(plan.problem.goal) <= FEWEST_LIMIT
    if plan.ok and small and all(len(step) == 1 for step in plan.steps):
        _fewest(plan)


def _plan_phases(plan: Plan, exact_limit: int) -> Kept:
    """Run the phases in turn, each on what the earlier ones left (:class:`_Run`), until
    one keeps a plan (:class:`Kept`); fill ``plan`` with it and return it. Each phase
    says in its docstring when it runs, what it leaves for the later ones and when it
    keeps a plan; the last always keeps one."""
    run = _Run.of(plan, exact_limit)
    for phase in (
        _front_walks,           # phase 0, compact goals: rows filled by lone walks
        _assigned_walks,        # phase 1: lone walks by the bound's assignment
        _bound_descent,         # large local fleets: descend the bound, relays, a few digs
        _relays_from_start,     # the relay heuristic from the start
        _relays_from_phase_1,   # ... and from where phase 1 stopped
        _front_if_no_longer,    # small fleets: phase 0's plan where it is no longer
        _descent_dug_on,        # relays stuck after a descent: its digs, carried on
        _reverse_problem,       # relays stuck: goal to start, played backwards
        _last_resort,           # still stuck: holes dug open, the shortest plan
        _forward_or_exact,      # the forward plan; stuck: the exact search (small fleets)
    ):
        kept = phase(run)
        if kept is not None:
            break
    else:
        raise AssertionError("the last phase always keeps a plan")
    plan.steps, plan.ok, plan.reason = kept.steps, kept.ok, kept.reason
    plan.notes += kept.notes
    return kept


@dataclass(frozen=True)
class Kept:
    """The plan a phase keeps: the phases after it do not run.

    ``phase`` names the phase; ``notes`` are added to the plan's (where it comes from);
    ``ok`` is False only where every phase stopped short, and ``reason`` then says why.
    ``lone_walks``: the plan is phase 0's or phase 1's walks alone -- each electron walks
    once, along a shortest path, to a void it keeps, so no module comes back to a cell and
    no configuration recurs, and :func:`plan_complete` does not shorten it (on the 5e5
    moves of a tree of 1000 modules shortening would spend 1 s finding nothing)."""

    phase: str
    steps: list[list[Move]]
    notes: tuple[str, ...] = ()
    ok: bool = True
    reason: str = ""
    lone_walks: bool = False


@dataclass
class _Run:
    """What the phases share: the problem, its size class, and what each phase leaves for
    the later ones (beside each field, the phase that writes it)."""

    planner: str
    problem: Problem
    exact_limit: int
    goal: set[Coord]
    #: :data:`COMPARE_LIMIT` modules or fewer: every phase runs, the shorter plan is kept.
    small: bool
    #: Over :data:`SMOOTH_LIMIT` modules: the relays advance (smoothing is too slow there),
    #: the bound may be descended, voids may be walled in, :data:`HOLE_CALLS_LARGE` digs.
    large: bool
    front: Plan | None = None                       # _front_walks
    first: Plan = field(init=False)                 # _assigned_walks, _relays_from_phase_1
    stopped: set[Coord] = field(default_factory=set)    # _assigned_walks: where it stopped
    walked: bool = False                            # _assigned_walks: it reached the goal
    descent: Heuristic | None = None                # _bound_descent
    dug_descent: Plan | None = None                 # _bound_descent, _descent_dug_on
    relays: Heuristic | None = None                 # _relays_from_start
    walled: bool = False                            # _relays_from_start
    #: The best forward plan so far: phase 1's, the relays', or phase 0's.
    forward: Plan = field(init=False)

    @classmethod
    def of(cls, plan: Plan, exact_limit: int) -> "_Run":
        goal = {xy(c) for c in plan.problem.goal}
        return cls(plan.planner, plan.problem, exact_limit, goal,
                   small=len(goal) <= COMPARE_LIMIT, large=len(goal) > SMOOTH_LIMIT)

    def new_plan(self) -> Plan:
        return Plan(self.planner, self.problem)

    def initial(self) -> set[Coord]:
        return {xy(c) for c in self.problem.initial}


def _front_walks(run: _Run) -> Kept | None:
    """Phase 0 (:class:`FrontWalk`), on small fleets and compact goals (rows to fill).
    Leaves its plan in ``run.front``; on a larger fleet, where it finishes, keeps it
    (lone walks)."""
    if not (run.small or compact(run.goal)):
        return None
    front = run.front = run.new_plan()
    front.ok = FrontWalk(front, run.initial()).run()
    if front.ok and not run.small:
        return Kept("front walks", front.steps, lone_walks=True)
    return None


def _assigned_walks(run: _Run) -> None:
    """Phase 1 (:class:`AssignWalk`), always: solves sparse shapes quickly and near the
    bound. Leaves its plan in ``run.first`` and where it stopped in ``run.stopped``.
    Where it finishes (``run.walked``) it is the forward plan, unless on a small fleet
    the relays from the start give a shorter one (cheap at this size)."""
    first = run.first = run.new_plan()
    run.stopped = run.initial()
    AssignWalk(first, run.stopped).run()
    run.walked = run.stopped == run.goal
    if not run.walked:
        return
    first.ok = True
    run.forward = first
    if run.small:
        relay = run.new_plan()
        Heuristic(relay).run()
        if relay.ok and _shortened_difference(relay, first) < 0:
            run.forward = relay


def _bound_descent(run: _Run) -> Kept | None:
    """Where phase 1 did not finish, on a large fleet whose voids are near their
    electrons (:func:`_local`, a local rearrangement): descend the bound, then the relays
    from there (:func:`_descended`, left in ``run.descent``), kept where they reach the
    goal. If they do not, a few digs from where they stopped (left in
    ``run.dug_descent``) are kept when short enough (:data:`DUG_EARLY`)."""
    if run.walked or not run.large or not _local(run.problem):
        return None
    descent = run.descent = _descended(run.planner, run.problem, run.large)
    if descent.plan.ok:
        return Kept("bound descent", descent.plan.steps, tuple(descent.plan.notes))
    run.dug_descent = _dug_descent(run.planner, run.problem, descent, DUG_EARLY_CALLS)
    return _dug_kept(run, run.dug_descent, DUG_EARLY)


def _relays_from_start(run: _Run) -> None:
    """Where phase 1 did not finish: the relay heuristic from the start (better on compact
    shapes), left in ``run.relays``; its plan is the forward plan. On a large fleet,
    stopped with more than :data:`FEW_VOIDS` voids left, it has walled voids in (holes,
    lakes; ``run.walled``): the relays from where phase 1 stopped and on the reverse
    problem stop too, after long searches, so only digging (the last resort) is tried.
    With a few voids left those runs often finish."""
    if run.walked:
        return
    run.forward = run.new_plan()
    relays = run.relays = Heuristic(run.forward, advance=run.large)
    relays.run()
    run.walled = run.large and len(run.goal - relays.occ) > FEW_VOIDS


def _relays_from_phase_1(run: _Run) -> None:
    """Where phase 1 did not finish and no voids are walled in: the relays carry phase 1's
    plan on from where it stopped (sometimes much shorter), and it becomes the forward
    plan if it finishes shorter. On large fleets only where the relays from the start
    are stuck (the time target)."""
    if run.walked or run.walled or (run.forward.ok and run.large):
        return
    first = run.first
    Heuristic(first, start=run.stopped, advance=run.large).run()
    if first.ok and (not run.forward.ok or _shortened_difference(first, run.forward) < 0):
        run.forward = first


def _front_if_no_longer(run: _Run) -> None:
    """Where phase 0 finished on a small fleet: its plan becomes the forward plan if the
    forward plan is stuck, or no shorter."""
    front = run.front
    if front is not None and front.ok and (
            not run.forward.ok or _shortened_difference(front, run.forward) <= 0):
        run.forward = front


def _descent_dug_on(run: _Run) -> Kept | None:
    """Where the bound was descended and the relays are stuck too: digging on from where
    the descent stopped (the rest of :data:`HOLE_CALLS_LARGE`, if its first digs did not
    finish) is kept if short enough (:data:`DUG_KEEP`): what runs after it takes far
    longer and seldom beats it. Otherwise it is one more try of the last resort."""
    if run.forward.ok or run.descent is None:
        return None
    assert run.dug_descent is not None
    if not run.dug_descent.ok:
        run.dug_descent = _dug_descent(run.planner, run.problem, run.descent,
                                       HOLE_CALLS_LARGE - DUG_EARLY_CALLS)
    return _dug_kept(run, run.dug_descent, DUG_KEEP)


def _reverse_problem(run: _Run) -> Kept | None:
    """Where the forward plan is stuck and no voids are walled in: the relays on the
    reverse problem (goal to start); kept, played backwards, if they finish (every move
    is reversible)."""
    if run.forward.ok or run.walled:
        return None
    p = run.problem
    backward = Plan(run.planner, Problem(p.goal, p.initial, p.fixed, p.obstacles, p.name))
    Heuristic(backward, advance=run.large).run()
    if not backward.ok:
        return None
    return Kept("reverse problem", reverse_steps(backward, p), (REVERSED_NOTE,))


def _last_resort(run: _Run) -> Kept | None:
    """Where the forward plan is still stuck: holes dug open and refilled, several ways
    (:func:`_last_resort_tries`); the shortest plan that finishes is kept, shortened
    (ties: the first tried). Gives up where none finishes."""
    if run.forward.ok:
        return None
    done = [(t, note) for t, note in _last_resort_tries(run) if t.ok]
    for t, _ in done:       # compared as they will be played; shortened here, the
        shorten(t)          # plan's notes say so before saying where it comes from
    if not done:
        return None
    best, note = min(done, key=lambda tn: tn[0].moves)     # ties: the first
    return Kept("last resort", best.steps, (*best.notes, note))


def _last_resort_tries(run: _Run) -> list[tuple[Plan, str]]:
    """The last resort's plans, each with the note that says where it comes from.

    Digging holes open and filling them (:meth:`Heuristic._hole_step`; long plans, but
    they reach the goal), by the relays from where they stopped (no other run failed
    here), and through smoothed shapes: fewer notches stop the walkers, so relays go
    further and less is dug. Both are tried: neither is always shorter. After a bound
    descent, digging on from where it stopped is a try too. On large fleets without a
    descent the relays also run again with pinned electrons first
    (:meth:`Heuristic._pinned`), digging where they stop: stuck relays have often walled
    electrons into cracks of the goal. Where voids are walled in (large fleets only),
    smoothed shapes go first and plain digging runs only when that fails (run first, it
    finished none)."""
    relays = run.relays
    assert relays is not None       # phase 1 did not finish, so the relays ran
    planner, p, advance = run.planner, run.problem, run.large
    calls = HOLE_CALLS_LARGE if run.large else HOLE_CALLS
    tries: list[tuple[Plan, str]] = []
    if run.dug_descent is not None and run.dug_descent.ok:
        tries.append((run.dug_descent, DESCENT_DUG_NOTE))
    smoothed = Plan(planner, p)
    if run.walled:
        if smoothed_plan(smoothed, advance=advance, hole_calls=calls):
            tries.append((smoothed, SMOOTHED_NOTE))
        else:
            dug = Plan(planner, p)
            relays.dig_on(dug)
            tries.append((dug, DUG_NOTE))
        return tries
    dug = Plan(planner, p)
    relays.dig_on(dug, calls)
    tries.append((dug, DUG_NOTE))
    # After a descent, pinned relays won none of the last resorts (the descent's digs or
    # the others were shorter): they run only without one.
    if run.large and run.descent is None:
        pinned = Heuristic(Plan(planner, p), advance=advance, pins=True)
        pinned.run()
        if pinned.plan.ok:
            tries.append((pinned.plan, PINNED_NOTE))
        else:
            dug = Plan(planner, p)
            pinned.dig_on(dug, calls)
            tries.append((dug, f"{PINNED_NOTE}, holes dug open and refilled"))
    smoothed_plan(smoothed, advance=advance, hole_calls=calls)
    tries.append((smoothed, SMOOTHED_NOTE))
    return tries


def _forward_or_exact(run: _Run) -> Kept:
    """Always keeps a plan: the forward plan where it finishes (lone walks if it is phase
    0's or phase 1's alone). Where it is stuck, small fleets (``exact_limit`` modules or
    fewer) finish by the exact search from where it stopped, which also proves
    unreachability (:func:`_finish_small`); larger ones say the heuristic is stuck."""
    forward = run.forward
    if forward.ok:
        lone = forward is run.front or (forward is run.first and run.walked)
        return Kept("forward", forward.steps, tuple(forward.notes), reason=forward.reason,
                    lone_walks=lone)
    stuck = Plan(run.planner, run.problem, steps=forward.steps, reason=forward.reason,
                 notes=list(forward.notes))
    _finish_small(stuck, {xy(c) for c in forward.configurations()[-1]}, run.exact_limit)
    return Kept("exact search" if stuck.ok else "stuck", stuck.steps, tuple(stuck.notes),
                ok=stuck.ok, reason=stuck.reason)


#: How the plans of the last phases say where they come from.
REVERSED_NOTE = "forward heuristic stuck; the reverse problem's plan played backwards"
DUG_NOTE = "relays stuck; holes dug open and refilled"
SMOOTHED_NOTE = ("relays stuck; start and goal smoothed (notches filled), holes dug open and "
                 "refilled")
PINNED_NOTE = "relays stuck; run again with pinned electrons first"
DESCENT_DUG_NOTE = "relays stuck; holes dug open and refilled from where bound descent stopped"


def compact(goal: set[Coord]) -> bool:
    """Whether ``goal`` is compact enough for front walks (:class:`FrontWalk`): rows to
    fill rather than branches to follow (on trees walks along the rows' order go far
    around the branches; the assigned walks do better there)."""
    links = sum(n in goal for c in goal for n in neighbours_xy(c))
    return bool(goal) and links >= COMPACT_DEGREE * len(goal)


def _local(p: Problem) -> bool:
    """Whether the assignment bound per electron is at most :data:`DESCENT_REACH`: each
    void is a few cells from its electron, as on scrambled blobs (2-3 cells; Eden blobs
    8-20, where bound descent spends its allowance and stops)."""
    electrons = len({xy(c) for c in p.initial} - {xy(c) for c in p.goal})
    return electrons > 0 and assignment_lower_bound(p.initial, p.goal) <= DESCENT_REACH * electrons


def _descended(planner: str, p: Problem, advance: bool) -> Heuristic:
    """Bound descent (:func:`planner_svc.planners.descent.descend`), then the relays from where it
    stopped (returned: their plan is ok if they reached the goal; if not, the last resort
    may dig on from there)."""
    initial = {xy(c) for c in p.initial}
    occ = set(initial)
    path, escapes, fills = descend(occ, {xy(c) for c in p.goal}, xy(p.fixed),
                                   {xy(c) for c in p.obstacles})
    plan = Plan(planner, p)
    plan.steps = play(initial, path)
    escaped, filled = sum(n for _, n in escapes), sum(n for _, n in fills)
    note = len(plan.notes)
    plan.notes.append(f"bound descent: {len(path)} moves, {len(path) - escaped - filled} of "
                      "them each lowering the assignment bound by one, "
                      f"{escaped} in {len(escapes)} window escapes"
                      + (f", {filled} in {len(fills)} fills" if fills else ""))
    relays = Heuristic(plan, start=occ, advance=advance)
    relays.run()
    # Said once the relays have run: the descent may have reached the goal alone.
    added = plan.moves - len(path)
    plan.notes[note] += ("; it reached the goal" if not added and plan.ok else
                         f"; relays from there: {added} moves" + ("" if plan.ok else
                                                                    ", stopped short"))
    return relays


def _dug_descent(planner: str, p: Problem, descent: Heuristic, calls: int) -> Plan:
    """Holes dug open and refilled (at most ``calls`` digs) from where the descent's
    relays stopped, or its last dig did; shortened (detours dropped) if that reached the
    goal."""
    dug = Plan(planner, p)
    dug.notes = list(descent.plan.notes)
    descent.dig_on(dug, calls)
    shorten(dug)
    return dug


def _dug_kept(run: _Run, dug: Plan, factor: float) -> Kept | None:
    """``dug`` (:func:`_dug_descent`), kept if it reached the goal in at most ``factor``
    times the assignment bound."""
    p = run.problem
    if not dug.ok or dug.moves > factor * assignment_lower_bound(p.initial, p.goal):
        return None
    return Kept("bound descent, dug on", dug.steps, (*dug.notes, DESCENT_DUG_NOTE))


def _shortened_difference(a: Plan, b: Plan) -> int:
    """Moves of ``a`` minus those of ``b``, both shortened first: candidate plans are
    compared as they will be played."""
    shorten(a)
    shorten(b)
    return a.moves - b.moves


def _finish_small(plan: Plan, occ: set[Coord], exact_limit: int) -> None:
    """The heuristic is stuck at ``occ``: finish with the exact search if the fleet is small."""
    n = len(occ)
    if n > exact_limit:
        voids = {xy(c) for c in plan.problem.goal} - occ
        plan.reason = (f"complete heuristic stuck after {plan.moves} moves with "
                       f"{len(voids)} voids left (not proven unreachable; "
                       f"{n} modules is too many for the exact search)")
        return
    before = plan.moves
    search_from(plan, occ, DEFAULT_MARGIN, EXACT_BUDGET)
    if plan.ok:
        plan.notes.append(f"heuristic stuck after {before} moves; exact search finished "
                          f"with {plan.moves - before} more")


def _fewest(plan: Plan) -> None:
    """Replace the plan of a small fleet by one with the fewest moves, if the exact search
    finds that it has more (and says so either way in the notes)."""
    p = plan.problem
    before = plan.moves
    if before <= assignment_lower_bound(p.initial, p.goal):
        return
    fewer = fewer_moves(plan, DEFAULT_MARGIN, FEWEST_BUDGET)
    within = f"within {DEFAULT_MARGIN} cells of start and goal"
    if fewer:
        plan.notes.append(f"exact search: {plan.moves} moves, the fewest {within} (the "
                          f"heuristics planned {before})")
    elif fewer is False:
        plan.notes.append(f"exact search: no plan {within} has fewer than these {before} "
                          "moves")

"""The order of ``complete``'s phases (:func:`plan_complete`): which run, on which
fleets, which plan is kept, and the notes that say where it comes from. See
:mod:`planner_svc.planners.complete` for the whole story, and docs/planner.md, *Measured
for what was kept*, for what the thresholds here gave when they were measured."""

from __future__ import annotations

from ..bounds import assignment_lower_bound
from ..descent import descend
from ..plan import Plan, Problem
from ..rules import Coord, neighbours_xy, xy
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


def _dug_kept(plan: Plan, dug: Plan, factor: float) -> bool:
    """Take ``dug`` (:func:`_dug_descent`) as ``plan`` if it reached the goal in at most
    ``factor`` times the assignment bound."""
    p = plan.problem
    if not dug.ok or dug.moves > factor * assignment_lower_bound(p.initial, p.goal):
        return False
    plan.steps, plan.ok = dug.steps, True
    plan.notes += dug.notes
    plan.notes.append(DESCENT_DUG_NOTE)
    return True


def plan_complete(plan: Plan, exact_limit: int = EXACT_LIMIT) -> None:
    """Fill ``plan`` (serial, one move per step); see the module docstring.

    If the heuristic gets stuck going forwards, it also tries the reverse problem
    (goal to initial) and plays that plan backwards, since every move is reversible.
    The plan is then shortened (:mod:`planner_svc.planners.shorten`, stretches re-planned in
    windows too), unless it is made of lone walks only (phases 0 and 1): each electron
    walks once, along a shortest path, to a void it keeps, so no module comes back to a
    cell and no configuration recurs (on the 5e5 moves of a tree of 1000 modules it
    would spend 1 s finding nothing).

    On fleets of :data:`FEWEST_LIMIT` modules or fewer, the exact search then looks for a
    plan with fewer moves (:func:`planner_svc.planners.exact.fewer_moves`, at most
    :data:`FEWEST_BUDGET` configurations) and takes it if there is one.
    """
    if not _plan_phases(plan, exact_limit):
        shorten(plan, windows=True)
    small = len(plan.problem.goal) <= FEWEST_LIMIT
    if plan.ok and small and all(len(step) == 1 for step in plan.steps):
        _fewest(plan)


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


def _shortened_difference(a: Plan, b: Plan) -> int:
    """Moves of ``a`` minus those of ``b``, both shortened first: candidate plans are
    compared as they will be played."""
    shorten(a)
    shorten(b)
    return a.moves - b.moves


def _plan_phases(plan: Plan, exact_limit: int) -> bool:
    """The phases of :func:`plan_complete`; True if the plan is lone walks only."""
    p: Problem = plan.problem
    goal = {xy(c) for c in p.goal}
    small = len(goal) <= COMPARE_LIMIT
    # Advances pay where smoothing is too slow to run (on Eden blobs of 100 modules they
    # do not beat the smoothed shapes' digging).
    advance = len(goal) > SMOOTH_LIMIT
    # Phase 0, front walks, on compact goals (rows to fill); at scale it is kept when it
    # finishes, small fleets keep the shortest plan of all phases.
    front: Plan | None = None
    if small or compact(goal):
        front = Plan(plan.planner, p)
        front.ok = FrontWalk(front, {xy(c) for c in p.initial}).run()
        if front.ok and not small:
            plan.steps, plan.ok = front.steps, True
            return True
    # Phase 1, assigned walks alone, solves sparse shapes quickly and near the bound. When
    # it cannot finish, the relay heuristic runs from the start (better on compact shapes)
    # and from where phase 1 stopped.
    first = Plan(plan.planner, p)
    occ = {xy(c) for c in p.initial}
    AssignWalk(first, occ).run()
    walked = occ == goal
    relays: Heuristic | None = None
    descent: Heuristic | None = None
    dug_descent: Plan | None = None
    walled = False
    if walked:
        first.ok = True
        forward = first
        if len(p.goal) <= COMPARE_LIMIT:        # cheap at this size: keep the shorter
            relay = Plan(plan.planner, p)
            Heuristic(relay).run()
            if relay.ok and _shortened_difference(relay, first) < 0:
                forward = relay
    else:
        # Large fleets whose voids are near their electrons (a local rearrangement)
        # descend the bound first; where that and relays from where it stopped reach
        # the goal, the plan is kept.
        if len(goal) > SMOOTH_LIMIT and _local(p):
            descent = _descended(plan.planner, p, advance)
            if descent.plan.ok:
                plan.steps, plan.ok = descent.plan.steps, True
                plan.notes += descent.plan.notes
                return False
            # Its relays are stuck: digging on from there is quick and, when short
            # enough, kept before the relays run from the start (see DUG_EARLY).
            dug_descent = _dug_descent(plan.planner, p, descent, DUG_EARLY_CALLS)
            if _dug_kept(plan, dug_descent, DUG_EARLY):
                return False
        forward = Plan(plan.planner, p)
        relays = Heuristic(forward, advance=advance)
        relays.run()
        # On large fleets, relays stopped with more than a few voids left have walled
        # voids in (holes, lakes): the relays from where phase 1 stopped and on the
        # reverse problem stop too, after long searches, and only digging (the last
        # resort) is tried. With a few voids left those runs often finish.
        walled = len(goal) > SMOOTH_LIMIT and len(goal - relays.occ) > FEW_VOIDS
        # Carrying on from where phase 1 stopped is sometimes much shorter; on large
        # fleets it only runs when needed (the time target).
        if not walled and (not forward.ok or len(goal) <= SMOOTH_LIMIT):
            Heuristic(first, start=occ, advance=advance).run()
            if first.ok and (not forward.ok or _shortened_difference(first, forward) < 0):
                forward = first
    if front is not None and front.ok and (
            not forward.ok or _shortened_difference(front, forward) <= 0):
        forward = front
    # Where the relays are stuck too, the descent's dig is kept if short enough: what
    # runs below takes far longer and seldom beats it (see DUG_KEEP).
    if not forward.ok and descent is not None:
        assert dug_descent is not None
        if not dug_descent.ok:          # it stopped early: dig on with the rest
            dug_descent = _dug_descent(plan.planner, p, descent,
                                       HOLE_CALLS_LARGE - DUG_EARLY_CALLS)
        if _dug_kept(plan, dug_descent, DUG_KEEP):
            return False
    if not forward.ok and not walled:
        backward = Plan(plan.planner, Problem(p.goal, p.initial, p.fixed, p.obstacles, p.name))
        Heuristic(backward, advance=advance).run()
        if backward.ok:
            plan.steps = reverse_steps(backward, p)
            plan.ok = True
            plan.notes.append("forward heuristic stuck; the reverse problem's plan played backwards")
            return False
    if not forward.ok:
        # Last resort: digging holes open and filling them (:meth:`Heuristic._hole_step`;
        # long plans, but they reach the goal), by the relays from where they stopped
        # (no other run failed here), and through smoothed shapes: fewer notches stop the
        # walkers, so relays go further and less is dug. Both are tried and the shortest
        # plan kept: neither is always shorter. After a bound descent, digging on from
        # where it stopped is a try too. On large fleets without a descent the relays
        # also run again with pinned electrons first (:meth:`Heuristic._pinned`),
        # digging where they stop: stuck relays have often walled electrons into cracks
        # of the goal. Where voids are walled in (large fleets only), smoothed shapes go
        # first and plain digging runs only when that fails (run first, it finished none).
        assert relays is not None
        large = len(goal) > SMOOTH_LIMIT
        calls = HOLE_CALLS_LARGE if large else HOLE_CALLS
        tries: list[tuple[Plan, str]] = []
        if dug_descent is not None and dug_descent.ok:
            tries.append((dug_descent, DESCENT_DUG_NOTE))
        smoothed = Plan(plan.planner, p)
        if walled:
            if smoothed_plan(smoothed, advance=advance, hole_calls=calls):
                tries.append((smoothed, SMOOTHED_NOTE))
            else:
                dug = Plan(plan.planner, p)
                relays.dig_on(dug)
                tries.append((dug, DUG_NOTE))
        else:
            dug = Plan(plan.planner, p)
            relays.dig_on(dug, calls)
            tries.append((dug, DUG_NOTE))
            # After a descent, pinned relays won none of the last resorts (the descent's
            # digs or the others were shorter): they run only without one.
            if large and descent is None:
                pinned = Heuristic(Plan(plan.planner, p), advance=advance, pins=True)
                pinned.run()
                if pinned.plan.ok:
                    tries.append((pinned.plan, PINNED_NOTE))
                else:
                    dug = Plan(plan.planner, p)
                    pinned.dig_on(dug, calls)
                    tries.append((dug, f"{PINNED_NOTE}, holes dug open and refilled"))
            smoothed_plan(smoothed, advance=advance, hole_calls=calls)
            tries.append((smoothed, SMOOTHED_NOTE))
        done = [(t, note) for t, note in tries if t.ok]
        for t, _ in done:       # compared as they will be played; shortened here, the
            shorten(t)          # plan's notes say so before saying where it comes from
        if done:
            best, note = min(done, key=lambda tn: tn[0].moves)     # ties: the first
            plan.steps, plan.ok = best.steps, True
            plan.notes += best.notes
            plan.notes.append(note)
            return False
    plan.steps, plan.ok, plan.reason = forward.steps, forward.ok, forward.reason
    plan.notes += forward.notes
    if not forward.ok:
        occ = {xy(c) for c in forward.configurations()[-1]}
        _finish_small(plan, occ, exact_limit)
        return False
    return forward is front or (forward is first and walked)


#: How the last resort's plans say where they come from.
DUG_NOTE = "relays stuck; holes dug open and refilled"
SMOOTHED_NOTE = ("relays stuck; start and goal smoothed (notches filled), holes dug open and "
                 "refilled")
PINNED_NOTE = "relays stuck; run again with pinned electrons first"
DESCENT_DUG_NOTE = "relays stuck; holes dug open and refilled from where bound descent stopped"


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

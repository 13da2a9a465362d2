"""Plan shortening: the shortened plan is legal, ends where the original ended, and is
shorter whenever the original wandered."""

import random

from planner_svc import planners
from planner_svc.planners.complete.steps import play
from planner_svc.planners.moves import lone_steps
from planner_svc.planners import shorten as shorten_module
from planner_svc.planners.bounds import random_blob, random_problem, scramble
from planner_svc.planners.plan import Plan, Problem, validate
from planner_svc.planners.rules import hex_distance, neighbours_xy, xy
from planner_svc.planners.shorten import drop_loops, drop_round_trips, legal, rebuild, shorten


def _random_walk_plan(n: int, moves: int, seed: int) -> Plan:
    """A legal plan of ``moves`` random rotations on a random blob of ``n`` modules."""
    rng = random.Random(seed)
    start = random_blob(n, rng)
    end, path = scramble(start, moves, rng)
    plan = Plan("random-walk", Problem.of(start, end, (0, 0)))
    plan.steps = play(set(start), path)
    plan.ok = True
    return plan


def _end(plan: Plan) -> set:
    return {xy(c) for c in plan.configurations()[-1]}


def test_shortened_random_walks_are_legal_end_in_place_and_shorter():
    saved = 0
    for seed in range(12):
        plan = _random_walk_plan(30, 120, seed)
        before, end = plan.moves, _end(plan)
        got = shorten(plan)
        validate(plan)                                  # every move legal, ends in the goal
        assert _end(plan) == end
        assert plan.moves == before - got
        saved += got
    # Random walks step back and forth all the time: a lot must go.
    assert saved > 12 * 120 // 4


def test_shortened_walks_among_obstacles_stay_legal():
    # Random walks among obstacles (a third of the free cells around a blob): the
    # shortened plan keeps to the rows the obstacles allow and still ends in place.
    saved = replanned = 0
    for seed in range(8):
        rng = random.Random(seed)
        start = random_blob(20, rng)
        rim = sorted({n for c in start for n in neighbours_xy(c)} - start)
        obstacles = set(rng.sample(rim, len(rim) // 3))
        occ, hops = set(start), []
        while len(hops) < 150:
            m = rng.choice(sorted(occ))
            steps = [g for _, g in lone_steps(occ, m, obstacles)]
            if not steps:
                continue
            g = rng.choice(steps)
            if legal(occ, m, g, (0, 0), obstacles) is None:
                continue
            hops.append((m, g))
            occ.discard(m)
            occ.add(g)
        plan = Plan("random-walk", Problem.of(start, occ, (0, 0), obstacles))
        plan.steps = rebuild(start, hops, (0, 0), frozenset(obstacles))
        plan.ok = True
        validate(plan)
        saved += shorten(plan)
        validate(plan)
        assert _end(plan) == occ
        # Windows keep off the obstacles: every move they re-plan (here in the raw walk)
        # is legal as it stands.
        for radius in shorten_module.WINDOW_RADII:
            fewer, _ = shorten_module.replan_windows(start, hops, (0, 0),
                                                     frozenset(obstacles), radius, 10 ** 6)
            assert rebuild(start, fewer, (0, 0), frozenset(obstacles)) is not None
            replanned += len(hops) - len(fewer)
    assert saved > 0 and replanned > 0


def test_a_configuration_loop_is_cut_out():
    a, b, c = (1, 0), (2, 0), (3, 0)
    # Whatever the moves, returning to the start configuration leaves nothing between.
    hops = [(a, b), (b, c), (c, b), (b, a), (a, b)]
    assert drop_loops({(0, 0), a}, hops) == [(a, b)]


def test_a_long_round_trip_goes_when_nothing_needs_it():
    # Line (0,0)-(1,0)-(2,0); the end module walks around its neighbour and back while
    # nobody else moves: the whole trip goes, however long.
    start = {(0, 0), (1, 0), (2, 0)}
    trip, occ, cur = [], set(start), (2, 0)
    for _ in range(3):                      # three steps to new cells around the line
        occ.discard(cur)
        g = next(g for _, g in lone_steps(occ, cur, set())
                 if g not in start and all(g != b for _, b in trip))
        trip.append((cur, g))
        occ.add(g)
        cur = g
    back = [(g, a) for a, g in reversed(trip)]
    assert len({g for _, g in trip}) == 3
    assert drop_round_trips(start, trip + back, (0, 0), frozenset()) == []


def test_nested_round_trips_go_in_one_pass():
    # X steps aside from (1, 1), Y steps into it and back, X steps back. X's trip is
    # needed only while Y's is there: trips are decided latest first, so Y's goes, then
    # X's, in the same pass (deciding X's first kept it for another round).
    start = {(0, 0), (1, 0), (2, 0), (1, 1)}
    hops = [((1, 1), (0, 1)), ((2, 0), (1, 1)), ((1, 1), (2, 0)), ((0, 1), (1, 1))]
    assert drop_round_trips(start, hops, (0, 0), frozenset()) == []


def test_overlapping_round_trips_of_one_module_keep_it_on_its_path():
    # One module: x -> y -> z -> y -> x -> y -> z. Its trips from z (moves 2-5) and from
    # y (moves 3-4) go; the trips from x (0-3) and y (1-2) share moves with the one from
    # z, which ends later, so they stay: dropping them too would leave the module at x.
    rest = {(0, 0), (1, 0), (0, 1)}
    x, y, z = (2, 0), (1, 1), (0, 2)
    assert {g for _, g in lone_steps(rest, x, set())} >= {y}
    assert {g for _, g in lone_steps(rest, y, set())} >= {x, z}
    hops = [(x, y), (y, z), (z, y), (y, x), (x, y), (y, z)]
    kept = drop_round_trips(rest | {x}, hops, (0, 0), frozenset())
    assert kept == [(x, y), (y, z)]


def test_round_trips_that_moves_in_between_need_stay():
    # On a crowded random walk some step-aside-and-back pairs are needed (a module in
    # between pivots on the one that stepped aside, or passes where it would wait):
    # those stay, and every hop kept is legal where it now stands.
    plan = _random_walk_plan(12, 300, 99)
    hops = [(xy(s[0].mobile), xy(s[0].goal)) for s in plan.steps]
    start = {xy(c) for c in plan.problem.initial}
    kept = drop_round_trips(start, hops, (0, 0), frozenset())
    returns = 0                             # kept hops whose module's next hop undoes them
    for i, (a, b) in enumerate(kept):
        after = next((g for m, g in kept[i + 1:] if m == b), None)
        returns += after == a
    assert 0 < returns and len(kept) < len(hops)
    occ = set(start)
    for m, g in kept:
        assert legal(occ, m, g, (0, 0), frozenset()) is not None, (m, g)
        occ.discard(m)
        occ.add(g)
    assert occ == _end(plan)


def test_complete_plans_come_out_shortened_and_legal(monkeypatch):
    # A dug plan (Eden blob of 40 modules, seed 2): digging peels a crater and puts it
    # back, and the window searches step modules aside and back; many of those go.
    problem = random_problem(40, 2)
    with monkeypatch.context() as m:
        m.setattr(shorten_module, "ROUNDS", 0)         # shortening off
        m.setattr(shorten_module, "WINDOW_ROUNDS", 0)
        raw = planners.get("complete").plan(problem)
    plan = planners.get("complete").plan(problem)
    validate(plan)
    assert raw.ok and plan.ok
    assert not any(n.startswith("shortened by") for n in raw.notes)
    assert plan.moves <= raw.moves - 20
    assert any(n.startswith("shortened by") for n in plan.notes)


def test_windows_replan_what_loops_and_round_trips_leave():
    # Random walks shortened as far as loops and round trips go still hold knots: in a
    # small window, fewer rotations give the same cells. Re-planned, each plan stays
    # legal, ends in place, is shorter again, and says so last.
    more = 0
    for seed in range(6):
        plan = _random_walk_plan(30, 120, seed)
        end = _end(plan)
        shorten(plan)
        first = plan.moves
        got = shorten(plan, windows=True)
        validate(plan)
        assert _end(plan) == end and plan.moves == first - got
        assert got == 0 or plan.notes[-1].startswith(shorten_module.WINDOWS_NOTE)
        more += got
    assert more >= 6 * 5


def test_a_window_skips_moves_far_from_it_and_plays_them_after_its_own():
    # Two blobs joined by a long bar, random walks in each, their moves alternating:
    # no two moves in a row are near each other, so every window found skips the
    # other blob's moves, which must still be legal once played after its own.
    rng = random.Random(3)
    left = random_blob(12, rng)
    right = {(x + 40, y) for x, y in random_blob(12, rng)}
    bar = {(x, 0) for x in range(0, 41)}
    start = left | right | bar
    occ, hops = set(start), []
    centres = [(0, 0), (40, 0)]
    while len(hops) < 160:
        centre = centres[len(hops) % 2]
        m = rng.choice(sorted(c for c in occ if hex_distance(c, centre) <= 4))
        steps = [g for _, g in lone_steps(occ, m, set())
                 if hex_distance(g, centre) <= 4]
        if not steps:
            continue
        g = rng.choice(steps)
        if legal(occ, m, g, (20, 0), frozenset()) is None:
            continue
        hops.append((m, g))
        occ.discard(m)
        occ.add(g)
    kept = drop_round_trips(start, drop_loops(start, hops), (20, 0), frozenset())
    sides = [a[0] < 20 for a, _ in kept]
    assert sum(x != y for x, y in zip(sides, sides[1:])) > len(kept) // 2
    new, left_over = shorten_module.replan_windows(start, kept, (20, 0), frozenset(), 3,
                                                   10 ** 6)
    assert len(new) <= len(kept) - 10 and left_over < 10 ** 6       # 52 -> 35
    steps = rebuild(start, new, (20, 0), frozenset())
    assert steps is not None
    validate(steps, [*start], [*occ], (20, 0))


def test_a_round_played_backwards_replans_what_forward_rounds_leave():
    # Forwards, a window is centred where a stretch starts; backwards, where it ends. On
    # these two random walks, windows forwards until nothing changes leave knots that
    # windows on the plan played backwards still find; the result, played forwards
    # again, is legal and ends in place.
    saved = 0
    for seed in (8, 18):
        plan = _random_walk_plan(30, 120, seed)
        shorten(plan)
        start, end = {xy(c) for c in plan.problem.initial}, _end(plan)
        hops = [(xy(s[0].mobile), xy(s[0].goal)) for s in plan.steps]
        while True:
            n = len(hops)
            for radius in shorten_module.WINDOW_RADII:
                hops, _ = shorten_module.replan_windows(start, hops, (0, 0), frozenset(),
                                                        radius, 10 ** 6)
            if len(hops) == n:
                break
        back = shorten_module._reversed(hops)
        for radius in shorten_module.WINDOW_RADII:
            back, _ = shorten_module.replan_windows(end, back, (0, 0), frozenset(), radius,
                                                    10 ** 6)
        again = shorten_module._reversed(back)
        steps = rebuild(start, again, (0, 0), frozenset())
        assert steps is not None
        validate(steps, [*start], [*end], (0, 0))
        saved += len(hops) - len(again)
    assert saved >= 5                                   # 34 -> 31, 36 -> 32


def test_window_rounds_alternate_direction(monkeypatch):
    # shorten's rounds: forwards, then backwards (each on the last round's result).
    seen = []
    real = shorten_module.replan_windows

    def spy(initial, hops, *args):
        seen.append(frozenset(initial))
        return real(initial, hops, *args)
    monkeypatch.setattr(shorten_module, "replan_windows", spy)
    plan = _random_walk_plan(30, 120, 8)
    start, end = {xy(c) for c in plan.problem.initial}, _end(plan)
    shorten(plan, windows=True)
    validate(plan)
    radii = len(shorten_module.WINDOW_RADII)
    assert seen[:2 * radii] == [start] * radii + [end] * radii

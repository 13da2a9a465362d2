"""The motion model (module_sim/physics.py, docs/physics.md) against Table 4-3 and the
Appendix A rotation sequences, plus every way a rotation can be refused."""

from __future__ import annotations

import math
from typing import Iterable, Sequence

import pytest
from hypothesis import given, settings, strategies as st

from bus import rotations
from bus.lattice import MOVE_RULES, Cell, Direction, Joint, MoveRule, move_rule, rotate_about_vertex
from bus.timing import TICK_NS
from module_sim.physics import (
    BREAKAWAY_NS, CARRY_NS, ROTATION_NS, Fault, ModuleSpec, MotionJudge, MoveCompleted,
    MoveRefused, MoveStarted, Outcome, PhysicsParams, Reason, orientation_after,
    rotation_arguments, rotation_degrees,
)

# --- firmware sequences: the one table in bus.rotations (spec §7) -------------------------
# ("open", k): JxOpen(i+k)   ("pos"/"neg", k): SxP/SxN(i+k)   ("wait", "t1"): DelayXts(t1)
MCW, MCCW, SCW = rotations.MCW, rotations.MCCW, rotations.SCW
SCCW_THESIS = rotations.SCCW_AS_RAN  # Appendix A as it ran: S(i-5) negative (spec §12)
SCCW_V2 = rotations.SCCW  # the comment's intent: S(i-5) positive

THESIS_TIMING = {"t1": 8, "t2": 4, "t3": 9}

State = tuple[int, tuple[bool, ...], tuple[int, ...]]


def timeline(seq: Sequence[tuple], i: int, t0_ns: int = 0, **timing: int) -> list[State]:
    """The actuator states a control board runs through for ``seq`` with argument ``i``.

    Statements between two waits take microseconds on the AVR: they count as one
    instant. Relays are tracked separately so SxP then SxN yields 2 (both on)."""
    ticks = {**THESIS_TIMING, **timing}
    joints, pos, neg = [False] * 6, [False] * 6, [False] * 6
    t, out = t0_ns, []

    def flush() -> None:
        mags = tuple(2 if p and n else 1 if p else -1 if n else 0 for p, n in zip(pos, neg))
        state = (t, tuple(joints), mags)
        if not out or out[-1][1:] != state[1:]:
            out.append(state)

    for op, *arg in seq:
        idx = (i + arg[0] - 1) % 6 if arg and op != "wait" else None
        if op == "wait":
            flush()
            t += ticks[arg[0]] * TICK_NS
        elif op == "open":
            joints[idx] = True
        elif op == "close_all":
            joints = [False] * 6
        elif op == "pos":
            pos[idx] = True
        elif op == "neg":
            neg[idx] = True
        elif op == "off_all":
            pos, neg = [False] * 6, [False] * 6
    flush()
    return out


def run(judge: MotionJudge, timelines: dict[str, list[State]],
        until_ns: int | None = None) -> list[Outcome]:
    """Feed merged timelines to the judge in time order, then let the clock run out."""
    # time order; at equal times each board's own statement order, boards interleaved
    events = sorted((t, n, k, mid, j, m) for k, (mid, tl) in enumerate(timelines.items())
                    for n, (t, j, m) in enumerate(tl))
    out: list[Outcome] = []
    for t, _, _, mid, j, m in events:
        out += judge.on_actuators(mid, t, j, m)
    end = until_ns if until_ns is not None else (events[-1][0] if events else 0) + ROTATION_NS + TICK_NS
    out += judge.advance(end)
    return out


def pair_world(rule: MoveRule, om: int = 0, os_: int = 0, extra: Iterable[ModuleSpec] = (),
               obstacles: Iterable[Cell] = ()) -> MotionJudge:
    """Mobile "m" at (0,0), fixed substrate "s" where ``rule`` wants it."""
    mobile = Cell(0, 0)
    sub, _, _ = rule.cells(mobile)
    mods = [ModuleSpec("m", mobile, om), ModuleSpec("s", sub, os_, fixed=True), *extra]
    return MotionJudge(mods, obstacles)


def rotation(rule: MoveRule, om: int = 0, os_: int = 0, sccw=SCCW_V2, mobile_seq=None,
             substrate_seq=None, **timing: int) -> dict[str, list[State]]:
    """The two timelines code 67/68 produces, with (mi, si) from rotation_arguments."""
    mi, si = rotation_arguments(rule, om, os_)
    cw = rule.direction is Direction.CW
    mseq = mobile_seq or (MCW if cw else MCCW)
    sseq = substrate_seq or (SCW if cw else sccw)
    return {"m": timeline(mseq, mi, **timing), "s": timeline(sseq, si, **timing)}


def kinds(out: list[Outcome]) -> list[type]:
    return [type(o) for o in out]


def refusals(out: list[Outcome], module: str = "m") -> list[MoveRefused]:
    return [o for o in out if isinstance(o, MoveRefused) and o.module == module]


ORIENTATIONS = [(0, 0), (1, 4), (5, 2), (3, 3)]


# --- every row of Table 4-3 ----------------------------------------------------------------
@pytest.mark.parametrize("om,os_", ORIENTATIONS)
@pytest.mark.parametrize("rule", MOVE_RULES, ids=lambda r: f"J{int(r.joint)}{r.direction.value}")
def test_firmware_rotation_moves_to_the_table_4_3_goal(rule, om, os_):
    judge = pair_world(rule, om, os_)
    out = run(judge, rotation(rule, om, os_))
    assert kinds(out) == [MoveStarted, MoveCompleted], out
    started, done = out
    _, _, goal = rule.cells(Cell(0, 0))
    assert done.to_cell == goal == judge.cell("m") and done.from_cell == Cell(0, 0)
    assert done.pivot_joint_global == rule.joint and done.direction == rule.direction
    assert done.orientation_after == orientation_after(om, rule.direction) == judge.orientation("m")
    # Timing: drive starts when the magnets come on (t1) and lasts ~220 ms.
    assert started.started_ns == done.started_ns == 8 * TICK_NS
    assert started.t_ns == 8 * TICK_NS + BREAKAWAY_NS
    assert done.t_ns == 8 * TICK_NS + ROTATION_NS
    assert judge.cell("s") == rule.cells(Cell(0, 0))[0]


@pytest.mark.parametrize("rule", MOVE_RULES, ids=lambda r: f"J{int(r.joint)}{r.direction.value}")
def test_orientation_change_is_the_rigid_rotation_about_the_pivot(rule):
    """Every body vertex of the mobile lands where rotating it 120 degrees about the pivot
    vertex puts it: checks the orientation sign and the CW/CCW naming at once."""
    start, om = Cell(0, 0), 2
    _, _, goal = rule.cells(start)
    pivot = start.vertex(rule.joint)
    o2 = orientation_after(om, rule.direction)
    for body in Joint:
        before = start.vertex(body + om)
        after = goal.vertex(body + o2)
        moved = rotate_about_vertex(before, pivot, rotation_degrees(rule.direction))
        assert math.dist(moved, after) < 1e-9
    assert math.dist(goal.vertex(rule.joint - om + o2), pivot) < 1e-9  # pivot stays put


def test_rotation_arguments_are_the_pivot_in_each_body_frame():
    for rule in MOVE_RULES:
        assert rotation_arguments(rule, 0, 0) == (int(rule.joint), int(rule.joint))
    r = move_rule(4, "CW")
    assert rotation_arguments(r, 1, 3) == (3, 1)
    assert rotation_arguments(r, 5, 0) == (5, 4)


@pytest.mark.parametrize("rule", MOVE_RULES, ids=lambda r: f"J{int(r.joint)}{r.direction.value}")
def test_each_required_empty_cell_blocks_the_move(rule):
    _, sweep, goal = rule.cells(Cell(0, 0))
    for cell in (goal, *sweep):
        judge = pair_world(rule, 1, 4, extra=[ModuleSpec("x", cell, 0)])
        out = run(judge, rotation(rule, 1, 4))
        (ref,) = refusals(out)
        assert ref.reason is (Reason.GOAL_OCCUPIED if cell == goal else Reason.SWEEP_OCCUPIED)
        assert "x" in ref.detail and str(cell) in ref.detail
        assert judge.cell("m") == Cell(0, 0)
        assert not any(isinstance(o, (MoveStarted, MoveCompleted)) for o in out)


def test_obstacle_counts_as_occupied():
    rule = move_rule(1, "CW")
    _, sweep, _ = rule.cells(Cell(0, 0))
    judge = pair_world(rule, obstacles=[sweep[2]])
    (ref,) = refusals(run(judge, rotation(rule)))
    assert ref.reason is Reason.SWEEP_OCCUPIED and "obstacle" in ref.detail


# --- wrong actuation, one reason each --------------------------------------------------------
ROW = move_rule(4, "CW")  # substrate D, goal C, must be empty A, B, H


def test_wrong_polarity_refused():
    swapped = tuple(("pos", a[0]) if op == "neg" else ("neg", a[0]) if op == "pos" else (op, *a)
                    for op, *a in SCW)
    judge = pair_world(ROW)
    out = run(judge, rotation(ROW, substrate_seq=swapped))
    (ref,) = refusals(out)
    assert ref.reason is Reason.WRONG_POLARITY and "needs negative" in ref.detail
    assert judge.cell("m") == Cell(0, 0)


def test_missing_substrate_refused():
    judge = MotionJudge([ModuleSpec("m", Cell(0, 0)), ModuleSpec("f", Cell(5, 5), fixed=True)])
    mi, _ = rotation_arguments(ROW, 0, 0)
    out = run(judge, {"m": timeline(MCW, mi)})
    (ref,) = refusals(out)
    assert ref.reason is Reason.MISSING_SUBSTRATE
    assert judge.cell("m") == Cell(0, 0)


def test_neighbour_still_latched_refused_and_released_neighbour_allows_the_move():
    # C (across side 3) is neither a sweep cell nor the goal of row J1 CW: a legal neighbour.
    rule = move_rule(1, "CW")
    c_cell = Cell(0, 0).neighbour(3)
    judge = pair_world(rule, extra=[ModuleSpec("n", c_cell, 2)])
    out = run(judge, rotation(rule))
    (ref,) = refusals(out)
    assert ref.reason is Reason.NEIGHBOUR_LATCHED
    owners = {(x["owner"], x["neighbour"]) for x in ref.data["latches"]}
    assert owners == {("m", "n"), ("n", "n")}  # the mobile's pin and the neighbour's pin
    # Table 3-2: the neighbour releases its pin on the shared edge and the mobile its own.
    judge = pair_world(rule, extra=[ModuleSpec("n", c_cell, 2)])
    n_pin = Joint.of(3 + 4 - 2)  # n's global joint s+4 in its body frame (o = 2)
    m_pin = Joint.of(3 + 1)
    tl = rotation(rule, mobile_seq=(("open", int(m_pin) - 1),) + MCW)  # i = 1
    tl["n"] = [(0, tuple(j == n_pin for j in Joint), (0,) * 6),
               (30 * TICK_NS, (False,) * 6, (0,) * 6)]
    out = run(judge, tl)
    assert kinds(out) == [MoveStarted, MoveCompleted], out


@pytest.mark.parametrize("rule", [ROW, move_rule(2, "CCW")], ids=["CW", "CCW"])
def test_delays_too_short_are_refused(rule):
    judge = pair_world(rule)
    out = run(judge, rotation(rule, t2=1))
    (ref,) = refusals(out)
    assert ref.reason is Reason.TOO_SHORT and ref.data["held_ns"] == TICK_NS
    assert judge.cell("m") == Cell(0, 0)
    judge = pair_world(rule)
    out = run(judge, rotation(rule, t1=0, t2=0, t3=0))
    assert refusals(out) and judge.cell("m") == Cell(0, 0)
    assert not any(isinstance(o, MoveCompleted) for o in out)


def test_magnets_cut_before_half_way_stall_and_fall_back():
    judge = pair_world(ROW)
    out = run(judge, rotation(ROW, t3=2))  # magnets on t2 + t3 = 6 ticks < 10
    assert kinds(out) == [MoveStarted, Fault]
    assert out[1].reason is Reason.STALLED and out[1].t_ns == (8 + 6) * TICK_NS
    assert judge.cell("m") == Cell(0, 0) and judge.in_flight() == {}


def test_both_relays_on_is_a_fault_and_a_refusal():
    fight = SCW[:3] + (("pos", -3),) + SCW[3:]  # SxP then SxN on the repelling side
    judge = pair_world(ROW)
    out = run(judge, rotation(ROW, substrate_seq=fight))
    faults = [o for o in out if isinstance(o, Fault)]
    assert [(f.module, f.reason) for f in faults] == [("s", Reason.BOTH_RELAYS)]
    (ref,) = refusals(out)
    assert ref.reason is Reason.BOTH_RELAYS
    assert judge.cell("m") == Cell(0, 0)


def test_fixed_module_never_moves():
    judge = MotionJudge([ModuleSpec("m", Cell(0, 0), fixed=True),
                         ModuleSpec("s", ROW.cells(Cell(0, 0))[0])])
    (ref,) = refusals(run(judge, rotation(ROW)))
    assert ref.reason is Reason.FIXED_MODULE and judge.cell("m") == Cell(0, 0)


@pytest.mark.parametrize("rule", MOVE_RULES[6:], ids=lambda r: f"J{int(r.joint)}CCW")
def test_thesis_sccw_defect_gives_no_attraction(rule):
    """SCCW as it ran energises both substrate sides at the pivot negative: refused."""
    judge = pair_world(rule, 2, 5)
    out = run(judge, rotation(rule, 2, 5, sccw=SCCW_THESIS))
    assert not any(isinstance(o, (MoveStarted, MoveCompleted)) for o in out)
    (ref,) = refusals(out, "m")
    assert ref.reason is Reason.NO_ATTRACTION and "SCCW" in ref.detail
    (sref,) = refusals(out, "s")  # the substrate shows a negative pair too; it is fixed
    assert sref.reason is Reason.FIXED_MODULE
    assert judge.cell("m") == Cell(0, 0)


def test_two_movers_cannot_take_the_same_goal():
    """m (J1 CW about s) and q (J3 CCW about qs) both aim at (-1,0); both moves are legal
    alone. q starts a tick later: m breaks away first and reserves the goal."""
    r1, r2 = move_rule(1, "CW"), move_rule(3, "CCW")
    q_cell = Cell(-2, 0)
    assert r1.cells(Cell(0, 0))[2] == r2.cells(q_cell)[2] == Cell(-1, 0)
    judge = MotionJudge([ModuleSpec("m", Cell(0, 0)), ModuleSpec("s", Cell(-1, 1), fixed=True),
                         ModuleSpec("q", q_cell), ModuleSpec("qs", r2.cells(q_cell)[0])])
    tl = rotation(r1)
    mi, si = rotation_arguments(r2, 0, 0)
    tl["q"] = timeline(MCCW, mi, t0_ns=TICK_NS)
    tl["qs"] = timeline(SCCW_V2, si, t0_ns=TICK_NS)
    out = run(judge, tl)
    assert [(type(o), o.module) for o in out if not isinstance(o, MoveRefused)] == [
        (MoveStarted, "m"), (MoveCompleted, "m")]
    (ref,) = refusals(out, "q")
    assert ref.reason is Reason.GOAL_OCCUPIED and "reserved by m" in ref.detail
    assert judge.cell("m") == Cell(-1, 0) and judge.cell("q") == q_cell


def test_next_deadline_and_advance():
    judge = pair_world(ROW)
    tl = rotation(ROW)
    for t, mid, j, m in sorted((t, mid, j, m) for mid in ("m", "s") for t, j, m in tl[mid][:2]):
        judge.on_actuators(mid, t, j, m)
    assert judge.next_deadline() == 8 * TICK_NS + BREAKAWAY_NS
    assert kinds(judge.advance(8 * TICK_NS + BREAKAWAY_NS)) == [MoveStarted]
    assert judge.next_deadline() == 8 * TICK_NS + CARRY_NS


# --- property: random actuation on a small random world ---------------------------------------
CELLS = [Cell(x, y) for x in range(-2, 3) for y in range(-2, 3) if Cell(0, 0).distance(Cell(x, y)) <= 2]

episode = st.tuples(
    st.integers(0, 5),  # mover index
    st.integers(0, 11),  # Table 4-3 row
    st.integers(0, 10), st.integers(0, 6), st.integers(0, 12),  # t1, t2, t3
    st.sampled_from(["firmware", "release", "thesis-sccw", "noise"]),
    st.integers(0, 40),  # start offset in ticks (episodes overlap)
    st.lists(st.tuples(st.integers(0, 5), st.integers(0, 5), st.sampled_from([-1, 0, 1, 2])),
             max_size=3),  # noise: (module, side, magnet value) flips
)


def grown(steps: list[tuple[int, int]]) -> list[Cell]:
    """A connected cluster: each step attaches a cell to an earlier one across a side."""
    cells = [Cell(0, 0)]
    for parent, side in steps:
        c = cells[parent % len(cells)].neighbour(side)
        if c not in cells:
            cells.append(c)
    return cells


def episode_timelines(judge: MotionJudge, ids: list[str], ep: tuple, t0: int) -> dict[str, list[State]]:
    """The actuator timelines of one random episode starting at ``t0``: a mover's rotation
    sequence about a row of Table 4-3 (preferring rows with a substrate where the judge
    has the modules now), its substrate's, Table 3-2's releases and noise. Keys name the
    module after their last ':'."""
    mover, row, t1, t2, t3, kind, _, noise = ep
    mid = ids[mover % len(ids)] if mover == 5 or len(ids) == 1 else ids[1 + mover % (len(ids) - 1)]
    occ = judge.occupancy()
    # prefer rows that have a substrate, so that moves actually happen
    supported = [r for r in MOVE_RULES if r.cells(judge.cell(mid))[0] in occ] or MOVE_RULES
    rule = supported[row % len(supported)]
    sub = occ.get(rule.cells(judge.cell(mid))[0])
    om = judge.orientation(mid)
    os_ = judge.orientation(sub) if sub else 0
    mi, si = rotation_arguments(rule, om, os_)
    cw = rule.direction is Direction.CW
    tls: dict[str, list[State]] = {}
    mseq = MCW if cw else MCCW
    if kind == "release":  # Table 3-2: the mobile and its other neighbours let go
        mseq = tuple(("open", k) for k in range(6)) + mseq
        for c in judge.cell(mid).neighbours():
            if (n := occ.get(c)) is not None and n != sub:
                tls[f"release:{n}"] = [(t0, (True,) * 6, (0,) * 6),
                                       (t0 + (t1 + t2 + 1) * TICK_NS, (False,) * 6, (0,) * 6)]
    tls[mid] = timeline(mseq, mi, t0, t1=t1, t2=t2, t3=t3)
    if sub and sub != mid and kind != "noise":
        sseq = SCW if cw else (SCCW_THESIS if kind == "thesis-sccw" else SCCW_V2)
        tls[sub] = timeline(sseq, si, t0, t1=t1, t2=t2, t3=t3)
    for k, (nm, side, val) in enumerate(noise):
        nid = ids[nm % len(ids)]
        mags = tuple(val if s == side else 0 for s in range(6))
        tls.setdefault(f"noise{k}:{nid}", []).append((t0 + (k + 3) * TICK_NS, (True,) * 6, mags))
        tls[f"noise{k}:{nid}"].append((t0 + (k + 5) * TICK_NS, (False,) * 6, (0,) * 6))
    return tls


def world_specs(growth: list[tuple[int, int]], orients: list[int], obstacle: Cell
                ) -> tuple[list[ModuleSpec], list[Cell]]:
    """A grown cluster of modules (the first one fixed) and an obstacle outside it."""
    cells = grown(growth)
    obstacles = [] if obstacle in cells else [obstacle]
    return [ModuleSpec(f"m{k}", c, orients[k % len(orients)], fixed=(k == 0))
            for k, c in enumerate(cells)], obstacles


@settings(max_examples=80)
@given(growth=st.lists(st.tuples(st.integers(0, 5), st.integers(1, 6)), min_size=1, max_size=5),
       orients=st.lists(st.integers(0, 5), min_size=6, max_size=6),
       obstacle=st.sampled_from(CELLS),
       episodes=st.lists(episode, min_size=1, max_size=6))
def test_random_actuation_never_overlaps_or_moves_the_fixed_module(growth, orients, obstacle, episodes):
    specs, obstacles = world_specs(growth, orients, obstacle)
    ids = [m.id for m in specs]
    judge = MotionJudge(specs, obstacles)
    long_way = MotionJudge(specs, obstacles)  # the reference long way: the same outcomes
    long_way.quick = False
    fixed_cell = specs[0].cell
    t_base = 0
    started: set[str] = set()
    for ep in episodes:
        tls = episode_timelines(judge, ids, ep, t_base + ep[6] * TICK_NS)
        events = sorted((t, n, key.split(":")[-1], j, m) for key, tl in tls.items()
                        for n, (t, j, m) in enumerate(tl))
        for t, _, who, j, m in events:
            outcomes = judge.on_actuators(who, max(t, judge.now_ns), j, m)
            assert outcomes == long_way.on_actuators(who, max(t, long_way.now_ns), j, m)
            for o in outcomes:
                check_outcome(o, started)
            check_world(judge, fixed_cell, ids[0], obstacles)
        t_base = max(t_base, events[-1][0]) + 5 * TICK_NS
    outcomes = judge.advance(t_base + ROTATION_NS + TICK_NS)
    assert outcomes == long_way.advance(t_base + ROTATION_NS + TICK_NS)
    assert judge.occupancy() == long_way.occupancy()
    for o in outcomes:
        check_outcome(o, started)
    check_world(judge, fixed_cell, ids[0], obstacles)


#: episodes whose magnets stay on for up to 0.7 s: attempts stay open (refused, waiting)
#: while other moves break away, stall and arrive around them
held_episode = st.tuples(st.integers(0, 8), st.integers(0, 11), st.integers(0, 30),
                         st.integers(0, 30), st.integers(0, 40),
                         st.sampled_from(["firmware", "release", "thesis-sccw", "noise"]),
                         st.integers(0, 60),
                         st.lists(st.tuples(st.integers(0, 9), st.integers(0, 5),
                                            st.sampled_from([-1, 0, 1, 2])), max_size=3))

#: timings where the deadlines tie: the default, break-away at the carry, carry at the arrival
PARAMS = [PhysicsParams(), PhysicsParams(breakaway_ns=CARRY_NS, carry_ns=CARRY_NS),
          PhysicsParams(carry_ns=ROTATION_NS),
          PhysicsParams(breakaway_ns=TICK_NS, carry_ns=2 * TICK_NS, rotation_ns=4 * TICK_NS)]


@settings(max_examples=150, deadline=None)
@given(growth=st.lists(st.tuples(st.integers(0, 8), st.integers(1, 6)), min_size=1, max_size=9),
       orients=st.lists(st.integers(0, 5), min_size=6, max_size=6),
       obstacle=st.sampled_from(CELLS),
       params=st.sampled_from(PARAMS),
       episodes=st.lists(held_episode, min_size=1, max_size=8),
       wakes=st.lists(st.integers(0, 80), max_size=6),
       relocations=st.lists(st.tuples(st.integers(0, 9), st.integers(1, 6), st.integers(0, 80)),
                            max_size=2))
def test_the_quick_way_gives_the_long_ways_outcomes(growth, orients, obstacle, params, episodes,
                                                     wakes, relocations):
    """Concurrent moves (episodes overlap in time), wakes between changes, relocated bodies:
    the quick way (deadline heap, only the attempts a change reaches re-evaluated, the
    short way) and the reference long way return the same outcomes, repr and data
    included, at every call, and agree on the next deadline and the world after each."""
    specs, obstacles = world_specs(growth, orients, obstacle)
    ids = [m.id for m in specs]
    quick, long_way = MotionJudge(specs, obstacles, params), MotionJudge(specs, obstacles, params)
    long_way.quick = False
    calls: list[tuple] = []  # (t, order, what, ...)
    for k, ep in enumerate(episodes):  # all laid out on the start positions: they overlap
        for key, tl in episode_timelines(quick, ids, ep, ep[6] * TICK_NS).items():
            calls += [(t, (k, n), "actuators", key.split(":")[-1], j, m) for n, (t, j, m) in enumerate(tl)]
    calls += [(w * TICK_NS + TICK_NS // 3, (-1, k), "wake") for k, w in enumerate(wakes)]
    calls += [(w * TICK_NS, (-2, k), "relocate", ids[i % len(ids)], side)
              for k, (i, side, w) in enumerate(relocations)]
    for t, _, what, *arg in sorted(calls):
        t = max(t, quick.now_ns)
        if what == "actuators":
            got, want = quick.on_actuators(arg[0], t, *arg[1:]), long_way.on_actuators(arg[0], t, *arg[1:])
        elif what == "wake":
            got, want = quick.advance(t), long_way.advance(t)
        else:  # a real module's body put where the planner confirmed it (one cell over)
            module, side = arg
            cell = quick.cell(module).neighbour(side)
            got, want = (_relocated(j, module, cell) for j in (quick, long_way))
        assert repr(got) == repr(want)
        assert quick.now_ns == long_way.now_ns
        assert quick.next_deadline() == long_way.next_deadline()
        assert quick.occupancy() == long_way.occupancy()
        assert quick.in_flight() == long_way.in_flight()
    end = quick.now_ns + params.rotation_ns + TICK_NS
    assert repr(quick.advance(end)) == repr(long_way.advance(end))
    assert {m: (quick.cell(m), quick.orientation(m)) for m in ids} == \
        {m: (long_way.cell(m), long_way.orientation(m)) for m in ids}


#: where racing movers start: within three cells of the origin
NEAR = [Cell(x, y) for x in range(-3, 4) for y in range(-3, 4) if Cell(0, 0).distance(Cell(x, y)) <= 3]
racer = st.tuples(st.sampled_from(NEAR), st.integers(0, 11),  # the mover's cell, Table 4-3 row
                  st.integers(0, 4), st.integers(0, 8),  # start tick, t1
                  st.integers(2, 6), st.integers(0, 12),  # t2, t3 (t2 + t3 < 10: a stall)
                  st.booleans())  # a CCW substrate runs SCCW as in the thesis (refused)


@settings(max_examples=200, deadline=None)
@given(racers=st.lists(racer, min_size=2, max_size=6), params=st.sampled_from(PARAMS),
       orients=st.lists(st.integers(0, 5), min_size=12, max_size=12))
def test_racing_moves_end_the_same_the_quick_way(racers, params, orients):
    """Movers a few cells apart, each with its substrate and every latch of its own
    released, start within four ticks of each other: their goals, sweeps, substrates and
    latches overlap, so one's break-away, stall or arrival changes what another's
    evaluation reads. The quick way and the long way give the same outcomes."""
    at: dict[Cell, str] = {}
    moves = []
    for cell, row, start, t1, t2, t3, thesis in racers:
        rule = MOVE_RULES[row]
        if cell in at and at[cell].startswith("s"):
            continue  # a substrate already: not a mover too
        mover = at.setdefault(cell, f"m{len(at)}")
        sub_cell = rule.cells(cell)[0]
        sub = at.setdefault(sub_cell, f"s{len(at)}")
        moves.append((mover, sub, rule, start, t1, t2, t3, thesis))
    specs = [ModuleSpec(m, c, orients[k % 12], fixed=(k == 1)) for k, (c, m) in enumerate(at.items())]
    orient = {s.id: s.orientation for s in specs}
    tls: dict[str, list[State]] = {m: [(0, (True,) * 6, (0,) * 6)] for m in orient}  # all released
    for mover, sub, rule, start, t1, t2, t3, thesis in moves:
        mi, si = rotation_arguments(rule, orient[mover], orient[sub])
        cw = rule.direction is Direction.CW
        timing = {"t1": t1, "t2": t2, "t3": t3}
        mseq = tuple(("open", k) for k in range(6)) + (MCW if cw else MCCW)
        tls[mover] += timeline(mseq, mi, (start + 1) * TICK_NS, **timing)
        tls[sub] += timeline(SCW if cw else SCCW_THESIS if thesis else SCCW_V2, si,
                             (start + 1) * TICK_NS, **timing)
    events = sorted((t, n, mid, j, m) for mid, tl in tls.items() for n, (t, j, m) in enumerate(tl))
    quick, long_way = MotionJudge(specs, (), params), MotionJudge(specs, (), params)
    long_way.quick = False
    moved = 0
    for t, _, mid, j, m in events:
        got = quick.on_actuators(mid, max(t, quick.now_ns), j, m)
        assert repr(got) == repr(long_way.on_actuators(mid, max(t, long_way.now_ns), j, m))
        assert quick.next_deadline() == long_way.next_deadline()
        moved += sum(isinstance(o, MoveStarted) for o in got)
    end = quick.now_ns + params.rotation_ns + TICK_NS
    assert repr(quick.advance(end)) == repr(long_way.advance(end))
    assert quick.occupancy() == long_way.occupancy()


@pytest.mark.parametrize("m_start,m_t2,expect", [
    (1, 4, [("x", MoveStarted), ("m", MoveRefused), ("x", MoveCompleted)]),  # reserved under m's drive
    (1, 25, [("x", MoveStarted), ("x", MoveCompleted), ("m", MoveStarted), ("m", MoveCompleted)]),
], ids=["reserved", "freed-by-arrival"])
def test_a_move_two_cells_away_reaches_a_mobiles_sweep(m_start, m_t2, expect):
    """x's sweep crosses (-1,-1), the far cell of m's sweep (Table 4-3's K), and nothing else
    m's evaluation reads: x's break-away must break m's drive (refused, sweep-occupied),
    and x's arrival must start m's waiting drive, the quick way as the long way."""
    m_rule, x_rule = move_rule(1, "CW"), move_rule(5, "CW")
    m_cell, x_cell = Cell(0, 0), Cell(-2, -1)
    assert set(m_rule.cells(m_cell)[1]) & set(x_rule.cells(x_cell)[1]) == {Cell(-1, -1)}
    specs = [ModuleSpec("m", m_cell), ModuleSpec("s", m_rule.cells(m_cell)[0], fixed=True),
             ModuleSpec("x", x_cell), ModuleSpec("xs", x_rule.cells(x_cell)[0])]
    tls = {"x": timeline(MCW, 5, 0, t1=0), "xs": timeline(SCW, 5, 0, t1=0),
           "m": timeline(MCW, 1, m_start * TICK_NS, t1=2, t2=m_t2),
           "s": timeline(SCW, 1, m_start * TICK_NS, t1=2, t2=m_t2)}
    outcomes = []
    for quick in (True, False):
        judge = MotionJudge(specs)
        judge.quick = quick
        outcomes.append(run(judge, tls))
    assert repr(outcomes[0]) == repr(outcomes[1])
    assert [(o.module, type(o)) for o in outcomes[0]] == expect
    if m_t2 == 4:
        assert outcomes[0][1].reason is Reason.SWEEP_OCCUPIED


def _relocated(judge: MotionJudge, module: str, cell: Cell) -> str:
    try:
        judge.relocate(module, cell, judge.orientation(module) + 1)
    except ValueError as exc:
        return str(exc)
    return "moved"


def check_outcome(o: Outcome, started: set[str]) -> None:
    if isinstance(o, MoveStarted):
        assert o.module not in started
        started.add(o.module)
    elif isinstance(o, MoveCompleted):
        assert o.module in started  # never a move without a start: no teleport
        started.discard(o.module)
        assert o.from_cell.distance(o.to_cell) == 1
    elif isinstance(o, Fault) and o.reason is Reason.STALLED:
        started.discard(o.module)


def check_world(judge: MotionJudge, fixed_cell: Cell, fixed_id: str, obstacles: list[Cell]) -> None:
    occ = judge.occupancy()
    assert len(occ) == len({judge.cell(m) for m in occ.values()})  # one module per cell
    assert judge.cell(fixed_id) == fixed_cell
    assert not set(occ) & set(obstacles)
    assert not set(judge.in_flight().values()) & set(occ)  # goals in flight stay empty

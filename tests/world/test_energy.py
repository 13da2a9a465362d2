"""Energy integration (module_sim/energy.py) against the thesis estimate of §4.4.2."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bus.lattice import Cell, Direction, Joint, move_rule
from bus.timing import NS_PER_S, TICK_NS
from module_sim.energy import LOGIC_W, MAGNET_W, SOLENOID_W, EnergyMeter
from module_sim.physics import MoveCompleted, MotionJudge
from test_physics import SCCW_V2, pair_world, rotation, run  # the firmware timeline generator

MS = 1_000_000
THESIS_J = 22.7


def feed(meter: EnergyMeter, judge: MotionJudge | None, timelines) -> list:
    """Give the meter (and the judge, if any) the same changes; returns the outcomes."""
    for mid, tl in timelines.items():
        for t, j, m in tl:
            meter.on_actuators(mid, t, j, m)
    return run(judge, timelines) if judge is not None else []


def test_thesis_estimate_is_reproduced_by_its_own_assumptions():
    """§4.4.2: 4 magnets, 8 solenoids (5 mobile, 3 neighbours) and the logic, all for
    100 ms: 227 W x 0.1 s = 22.7 J. Checks the integrator, to float precision."""
    on = lambda k: tuple(i < k for i in range(6))  # noqa: E731
    mags2 = (-1, -1, 0, 0, 0, 0)
    tl = {"m": [(0, on(5), mags2), (100 * MS, on(0), (0,) * 6)],
          "s": [(0, on(1), (-1, 1, 0, 0, 0, 0)), (100 * MS, on(0), (0,) * 6)],
          "n1": [(0, on(1), (0,) * 6), (100 * MS, on(0), (0,) * 6)],
          "n2": [(0, on(1), (0,) * 6), (100 * MS, on(0), (0,) * 6)]}
    meter = EnergyMeter()
    feed(meter, None, tl)
    move = MoveCompleted("m", 220 * MS, 0, Cell(0, 0), Cell(-1, 0), Joint(1), Direction.CW,
                         0, 2, "s", ("m", "s", "n1", "n2"))
    e = meter.record_move(move)
    assert e.magnets_j == pytest.approx(19.2)
    assert e.solenoids_j == pytest.approx(2.0)
    assert e.logic_j == pytest.approx(1.5)
    assert e.total_j == pytest.approx(THESIS_J, abs=1e-9)
    assert meter.run_energy(300 * MS).total_j == pytest.approx(THESIS_J, abs=1e-9)


def test_firmware_cw_move_energy():
    """MCW + SCW with t1=8, t2=4, t3=9 ticks, integrated exactly.

    Mobile: J_i, J_i+1 open 12 ticks; S_i, S_i-1 on 13 ticks. Substrate: J_i-1 open 21
    ticks, J_i-2 9 ticks; two magnets 13 ticks. Logic: the actuation interval, 21 ticks.
    Tolerance against 22.7 J: the thesis assumes "nearly 100 ms" for every actuator; the
    firmware keeps the magnets (85 % of the budget) on 13 ticks = 129.8 ms, so the exact
    figure must exceed 22.7 J by up to ~30 %; we require 22.7 J <= E <= 1.3 x 22.7 J, and
    the analytic value to 1 uJ.
    """
    rule = move_rule(4, "CW")
    judge, meter = pair_world(rule), EnergyMeter()
    out = feed(meter, judge, rotation(rule))
    (done,) = [o for o in out if isinstance(o, MoveCompleted)]
    e = meter.record_move(done)
    tick_s = TICK_NS / NS_PER_S
    assert e.magnets_j == pytest.approx(4 * MAGNET_W * 13 * tick_s, abs=1e-6)
    assert e.solenoids_j == pytest.approx(SOLENOID_W * (2 * 12 + 21 + 9) * tick_s, abs=1e-6)
    assert e.logic_j == pytest.approx(LOGIC_W * 21 * tick_s, abs=1e-6)
    assert e.total_j == pytest.approx(29.4131, abs=1e-3)
    assert THESIS_J <= e.total_j <= 1.3 * THESIS_J
    assert meter.move_window(done) == (0, 21 * TICK_NS, done.t_ns)


def test_firmware_ccw_move_energy_v2():
    """MCCW + SCCW (v2, S(i-5) positive): same magnets; solenoids J_i+1 21 ticks and J_i
    9 ticks on the mobile, J_i-3 and J_i-4 12 ticks each on the substrate."""
    rule = move_rule(2, "CCW")
    judge, meter = pair_world(rule), EnergyMeter()
    out = feed(meter, judge, rotation(rule, sccw=SCCW_V2))
    (done,) = [o for o in out if isinstance(o, MoveCompleted)]
    e = meter.record_move(done)
    tick_s = TICK_NS / NS_PER_S
    assert e.solenoids_j == pytest.approx(SOLENOID_W * (21 + 9 + 2 * 12) * tick_s, abs=1e-6)
    assert e.total_j == pytest.approx(29.4131, abs=1e-3)


def test_relay_fight_counts_one_coil_and_windows_are_exact():
    meter = EnergyMeter()
    meter.on_actuators("a", 0, (False,) * 6, (2, 0, 0, 0, 0, 0))
    meter.on_actuators("a", 10 * MS, (True, False, False, False, False, False), (0,) * 6)
    meter.on_actuators("a", 30 * MS, (False,) * 6, (0,) * 6)
    assert meter.actuator_energy(["a"], 0, 100 * MS).magnets_j == pytest.approx(MAGNET_W * 0.01)
    assert meter.actuator_energy(["a"], 5 * MS, 20 * MS).total_j == pytest.approx(
        MAGNET_W * 0.005 + SOLENOID_W * 0.01)
    assert meter.burst_start("a", 25 * MS) == 0 and meter.burst_start("a", 40 * MS) is None
    assert meter.per_module(100 * MS)["a"].solenoids_j == pytest.approx(SOLENOID_W * 0.02)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 50), st.integers(0, 2), st.integers(0, 2)), min_size=1, max_size=30),
       st.integers(0, 1500), st.integers(0, 1500))
def test_last_release_equals_a_walk_from_the_first_change_point(changes, start, span):
    """last_release starts at the segment holding ``start``: the same answer as a walk over
    the module's whole history."""
    meter = EnergyMeter()
    t = 0
    for dt, joints, magnets in changes:
        t += dt * 10
        meter.on_actuators("m1", t, [True] * joints + [False] * (6 - joints), [1] * magnets + [0] * (6 - magnets))
    end = start + span
    tr = meter._tracks["m1"]
    walked = None
    for k, tk in enumerate(tr.times):
        if tk > end:
            break
        if tr.active(k):
            seg_end = tr.times[k + 1] if k + 1 < len(tr.times) else end
            if seg_end >= start:
                walked = min(seg_end, end)
    assert meter.last_release("m1", start, end) == walked

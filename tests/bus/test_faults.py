"""Actuator fault specs (bus/faults.py): one format for scenarios, the CLI and the bus."""

import pytest

from bus.faults import ActuatorFault, FaultSpecError
from bus.lattice import NEIGHBOUR_OFFSET, Side, rotate_offset
from bus.scenario import ScenarioError, load, loads, override


@pytest.mark.parametrize("spec,commanded,effective", [
    ("m3.S2-:off", [0, -1, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]),
    ("m3.S2-:off", [0, 1, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0]),
    ("m3.S2-:off", [0, 2, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0]),  # the fight becomes positive only
    ("m3.S2+:off", [0, 2, 0, 0, 0, 0], [0, -1, 0, 0, 0, 0]),
    ("m3.S2:off", [-1, 1, 1, 0, 0, 0], [-1, 0, 1, 0, 0, 0]),
])
def test_magnet_relay_faults(spec, commanded, effective):
    f = ActuatorFault.parse(spec)
    assert str(f) == spec
    joints, mags = f.apply([True] * 6, commanded)
    assert mags == effective and joints == [True] * 6


def test_stuck_solenoid():
    f = ActuatorFault.parse("m12.J4:closed")
    assert (f.module, f.part, f.index) == ("m12", "joint", 4)
    assert f.apply([True] * 6, [0] * 6)[0] == [True, True, True, False, True, True]
    assert "solenoid J4 stuck closed" in f.describe()


@pytest.mark.parametrize("bad", ["m3.S7:off", "m3.J2:off", "3.S2:off", "m3.S2-:on", ""])
def test_bad_specs_say_what_is_accepted(bad):
    with pytest.raises(FaultSpecError, match=r"expected m<id>\.S<1-6>\[\+\|-\]:off"):
        ActuatorFault.parse(bad)


def test_scenario_faults_are_checked():
    sc = loads('faults = ["m2.J1:closed"]\ninitial = [[0, 0], [1, 0]]\n')
    assert [str(f) for f in sc.faults] == ["m2.J1:closed"]
    with pytest.raises(ScenarioError, match=r"faults\[0\].*a fault on a module of this scenario"):
        loads('faults = ["m5.J1:closed"]\ninitial = [[0, 0], [1, 0]]\n')
    with pytest.raises(ScenarioError, match=r"faults\[0\]"):
        loads('faults = ["m2.X1:closed"]\ninitial = [[0, 0], [1, 0]]\n')
    assert [str(f) for f in override(load("pair"), faults=["m1.S3:off"]).faults] == ["m1.S3:off"]
    with pytest.raises(ScenarioError, match="has no module m7"):
        override(load("pair"), faults=["m7.S3:off"])


def test_rotate_offset_turns_sides():
    for s in Side:
        for k in range(7):
            assert rotate_offset(NEIGHBOUR_OFFSET[s], k) == NEIGHBOUR_OFFSET[Side.of(s + k)]

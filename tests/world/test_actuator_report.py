"""The v2 actuator report (docs/protocol.md): the control board's solenoid and magnet bits as
``ACT`` lines on its debug UART, one per step of a command, never during the boot."""

from __future__ import annotations

import pytest

from bus import codec
from bus.codec import Kind, Link
from bus.functions import FunctionCode as F
from bus.messages import Actuators
from bus.scenario import loads
from fleet_rig import FleetRig

ONE = '[[modules]]\ncell = [0, 0]\nid = 1\n'


def test_the_report_round_trips_and_frames_among_debug_lines():
    joints, magnets = [True, False, False, True, False, True], [1, -1, 0, 2, 0, -1]
    line = codec.encode_actuator_report(joints, magnets)
    # mask bytes may be 0x0a or 0x0d: the template's fixed length frames them anyway
    frame = codec.parse(Link.DEBUG, line)
    assert frame.kind is Kind.ACTUATORS
    assert frame.view["joints_open"] == joints and frame.view["magnets"] == magnets
    assert line[3] == 0b101001 and line[4] == 0b1001 and line[5] == 0b101010


def _debug(profile: str) -> tuple[FleetRig, list]:
    rig = FleetRig("act", loads(f'profile = "{profile}"\n' + ONE))
    seen: list = []
    rig.bus.subscribe_frames(seen.append, "debug")
    return rig, seen


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_a_rotation_is_reported_step_by_step_under_v2_only(profile):
    rig, seen = _debug(profile)
    try:
        rig.boot()
        # the boot's joint test changed the solenoids, but nothing was reported
        assert not [e for e in seen if e.kind == Kind.ACTUATORS.value]
        rig.pc.ack(F.MCW, 3, 8, 4, 9)
        rig.run_for(1.0)
        reports = [e for e in seen if e.kind == Kind.ACTUATORS.value]
        if profile == "thesis-2009":
            assert not reports
            return
        module = rig.fleet.modules[1]
        # one report per step: joints open, magnets on, joints closed, magnets off
        assert len(reports) == 4
        assert reports[-1].view["joints_open"] == [False] * 6 and reports[-1].view["magnets"] == [0] * 6
        assert sum(reports[0].view["joints_open"]) == 2  # J(i), J(i+1)
        assert reports[1].view["magnets"].count(-1) == 2  # S(i), S(i-1) negative
        assert module.actuators().joints_open == [False] * 6
        # each report starts on the wire when its step changed the ports: the steps are
        # t1 = 8 and t2 = 4 ticks apart, the report 8 bytes at 4800 baud
        t = [e.first_byte_ns for e in reports]
        assert t[1] - t[0] >= 7 * 9_984_000 and t[2] - t[1] >= 3 * 9_984_000
    finally:
        rig.close()


def test_a_real_body_follows_its_twin_until_the_board_reports_differ():
    rig = FleetRig("act", loads('[[modules]]\ncell = [0, 0]\nid = 1\n'
                                '[[modules]]\ncell = [1, 0]\nid = 2\nkind = "real"\n'))
    mech = rig.fleet.world.mechanics
    try:
        rig.boot()
        twin_bits = mech.bits("m2")
        assert twin_bits is not None and set(rig.fleet.twins) == {2}
        board = Actuators("m2", rig.clock.now_ns(), [True] + [False] * 5, [1] + [0] * 5,
                          [False] * 6, [False] * 6, [False] * 6, None, origin="serial")
        rig.bus.put(rig.bus.keys.actuators("m2"), board.to_json())
        rig.run_for(0.1)
        assert mech.bits("m2") == twin_bits  # the twin's bits, while the board agrees
        rig.bus.event("m2", "twin-diverged", link="centre")
        rig.run_for(0.1)
        assert mech.bits("m2") == twin_bits  # an answer that differs is not the body's business
        rig.bus.event("m2", "twin-diverged", link="debug")
        rig.run_for(0.1)
        assert mech.board_bits == {"m2"}
        assert mech.bits("m2") == ([True] + [False] * 5, [1] + [0] * 5)  # the board's, at once
        rig.fleet.twins[2].ctrl.JxOpen(4)  # the twin's bits no longer move the body
        rig.run_for(0.1)
        assert mech.bits("m2") == ([True] + [False] * 5, [1] + [0] * 5)
    finally:
        rig.close()


def test_ir_bit_errors_are_events():
    rig = FleetRig("ber", loads('bit_error_rate = 0.01\n[[modules]]\ncell = [0, 0]\nid = 1\n'
                                '[[modules]]\ncell = [1, 0]\nid = 2\n'))
    try:
        rig.boot()
        errors = [e for e in rig.bus_events if e["kind"] == "bit-error"]
        assert errors and all(e["bits"] > 0 and e["receiver"] in ("pc", "m1", "m2") for e in errors)
    finally:
        rig.close()

"""Moves end to end: PC frames on the centre IR channel -> both boards' programs -> port
bits -> the world's physics -> poses and events on the bus (issue: the world)."""

from __future__ import annotations

import random

import pytest

from bus.functions import FunctionCode as F
from bus.lattice import MOVE_RULES, Cell, Direction, MoveRule
from bus.messages import Energy, Pose, WorldEvent
from bus.scenario import loads
from module_sim.physics import orientation_after, rotation_arguments

from fleet_rig import BOOTED_S, FleetRig

THESIS = (8, 4, 9)


class Rig(FleetRig):
    """A fleet, a PC endpoint and everything the world says, on one private bus."""

    def __init__(self, toml: str, power: bool = True) -> None:
        super().__init__("moves", loads(toml))
        self.events: list[WorldEvent] = []
        self.poses: dict[str, Pose] = {}
        self.energy: list[Energy] = []
        root = self.bus.keys.root
        self.bus.subscribe(f"{root}/world/event", lambda k, p: self.events.append(WorldEvent.from_json(p)))
        self.bus.subscribe(f"{root}/world/pose/*", self._pose)
        self.bus.subscribe(f"{root}/world/energy", lambda k, p: self.energy.append(Energy.from_json(p)))
        if power:
            self.boot()

    def _pose(self, key: str, payload: bytes) -> None:
        p = Pose.from_json(payload)
        self.poses[p.module] = p

    def kinds(self, module: str | None = None) -> list[str]:
        return [e.kind for e in self.events if module is None or e.module == module]


def pair_toml(rule: MoveRule, om: int, os_: int, obstacles: list[Cell] = (),
              profile: str = "v2", faults: list[str] = ()) -> str:
    mobile = Cell(0, 0)
    sub, _, goal = rule.cells(mobile)
    obs = ", ".join(f"[{c.x}, {c.y}]" for c in obstacles)
    flt = ", ".join(f'"{f}"' for f in faults)
    return (f'profile = "{profile}"\nfixed = [{sub.x}, {sub.y}]\n'
            f"goal = [[{sub.x}, {sub.y}], [0, 0]]\nobstacles = [{obs}]\n"
            f"faults = [{flt}]\n"
            f"[[modules]]\nid = 1\ncell = [0, 0]\norientation = {om}\n"
            f"[[modules]]\nid = 2\ncell = [{sub.x}, {sub.y}]\norientation = {os_}\n")


def send_move(rig: Rig, rule: MoveRule, om: int, os_: int, timing=THESIS) -> None:
    mi, si = rotation_arguments(rule, om, os_)
    d = 1 if rule.direction is Direction.CW else 2
    rig.pc.send(F.Move, d, 1, mi, 2, si, *timing)
    rig.run_for(3.0)


@pytest.mark.parametrize("rule", MOVE_RULES, ids=lambda r: f"J{int(r.joint)}-{r.direction.value}")
def test_every_table_4_3_row_moves_by_the_move_code(rule: MoveRule):
    """Random orientations: the body-frame arguments must land on the global rule."""
    rnd = random.Random(int(rule.joint) * 10 + (rule.direction is Direction.CW))
    om, os_ = rnd.randrange(6), rnd.randrange(6)
    rig = Rig(pair_toml(rule, om, os_))
    try:
        send_move(rig, rule, om, os_)
        _, _, goal = rule.cells(Cell(0, 0))
        assert rig.kinds("m1") == ["move-started", "move-completed"], rig.events
        done = rig.events[-1]
        assert done.data["to"] == [goal.x, goal.y] and done.data["substrate"] == "m2"
        pose = rig.poses["m1"]
        assert (pose.x, pose.y) == (goal.x, goal.y)
        assert pose.orientation == orientation_after(om, rule.direction)
        assert rig.fleet.world.bodies["m2"].cell == rule.cells(Cell(0, 0))[0]  # substrate stays
        # ~220 ms rotation from the drive start; energy published for the move
        assert 200e6 < done.data["duration_ns"] < 240e6
        (e,) = [x for x in rig.energy if x.module == "m1"]
        assert 22.7 <= e.move_j <= 1.3 * 22.7
    finally:
        rig.close()


@pytest.mark.parametrize("which", ["sweep", "goal"])
def test_a_required_cell_occupied_refuses_the_move(which: str):
    rule = MOVE_RULES[3]
    _, sweep, goal = rule.cells(Cell(0, 0))
    blocked = sweep[0] if which == "sweep" else goal
    rig = Rig(pair_toml(rule, 0, 0, obstacles=[blocked]))
    try:
        send_move(rig, rule, 0, 0)
        assert "move-started" not in rig.kinds()
        (ref,) = [e for e in rig.events if e.kind == "move-refused" and e.module == "m1"]
        assert ref.reason == ("sweep-occupied" if which == "sweep" else "goal-occupied")
        assert "obstacle" in ref.data["detail"]
        assert (rig.poses["m1"].x, rig.poses["m1"].y) == (0, 0)
    finally:
        rig.close()


def test_thesis_combined_cw_code_moves_the_pair():
    """thesis-2009 has no addressing: the reference is powered first and made the
    substrate with ``Ref`` (M=0, S=1) before the mobile module is switched on (M=1).
    Then one ``CW`` frame (code 67) moves the pair; the substrate's 1 s ACK delay keeps
    the two ACKs from colliding at the PC."""
    rule = MOVE_RULES[2]
    rig = Rig(pair_toml(rule, 0, 0, profile="thesis-2009"), power=False)
    try:
        world, mods = rig.fleet.world, rig.fleet.modules
        world.start()
        mods[2].power_up()
        rig.run_for(BOOTED_S)
        rig.pc.ack(F.Ref)
        mods[1].power_up()
        rig.run_for(BOOTED_S)
        mi, si = rotation_arguments(rule, 0, 0)
        mark = len(rig.pc.received)
        rig.pc.send(F.CW, si, *THESIS, mi, *THESIS)
        first = rig.pc.expect("ack", since=mark, timeout_s=3)
        second = rig.pc.expect("ack", since=mark + 1 + rig.pc.received[mark:].index(first),
                               timeout_s=3)
        assert (first.frame.view["byte"], first.frame.view.get("role")) == (F.MCW, "M")
        assert (second.frame.view["byte"], second.frame.view.get("role")) == (F.SCW, "S")
        assert second.t_first_ns - first.t_last_ns > 0.3e9  # the substrate waited
        rig.run_for(1.0)
        assert "collision" not in [e.get("kind") for e in rig.bus_events]
        assert rig.kinds("m1") == ["move-started", "move-completed"]
        _, _, goal = rule.cells(Cell(0, 0))
        assert world.bodies["m1"].cell == goal
    finally:
        rig.close()


def test_a_stuck_solenoid_on_the_mobile_leaves_it_latched():
    """Sabotage through the bus (``world/inject``): the mobile's solenoid that unlatches
    it from the substrate never opens -> refused, naming the latch."""
    rule = MOVE_RULES[5]
    om, os_ = 1, 4
    rig = Rig(pair_toml(rule, om, os_))
    try:
        mi, _ = rotation_arguments(rule, om, os_)
        # CW about global joint j: the mobile's pin at vertex j+1 holds the substrate
        # (the pin at j is the hinge); its body joint is mi+1.
        stuck = (mi % 6) + 1
        rig.bus.put_json(rig.bus.keys.world_inject, {"fault": f"m1.J{stuck}:closed"})
        rig.run_for(0.1)
        assert rig.events[-1].kind == "fault-injected"
        send_move(rig, rule, om, os_)
        assert "move-started" not in rig.kinds()
        refused = [e for e in rig.events if e.kind == "move-refused" and e.module == "m1"]
        assert [e.reason for e in refused] == ["neighbour-latched"]
        assert f"solenoid J{stuck} closed" in refused[0].data["detail"]
    finally:
        rig.close()


def test_a_magnet_relay_stuck_off_on_the_substrate_is_wrong_polarity():
    """A scenario fault: the substrate's negative relay on the side facing the mobile
    is stuck off, so nothing repels."""
    rule = MOVE_RULES[1]
    om, os_ = 2, 5
    _, si = rotation_arguments(rule, om, os_)
    toward = int(rule.joint) if rule.direction is Direction.CW else int(rule.joint) - 1
    repel_body = (toward + 3 - os_ - 1) % 6 + 1
    rig = Rig(pair_toml(rule, om, os_, faults=[f"m2.S{repel_body}-:off"]))
    try:
        send_move(rig, rule, om, os_)
        assert "move-started" not in rig.kinds()
        (ref,) = [e for e in rig.events if e.kind == "move-refused" and e.module == "m1"]
        assert ref.reason == "wrong-polarity"
        assert f"body side {repel_body} facing the mobile is off" in ref.data["detail"]
    finally:
        rig.close()

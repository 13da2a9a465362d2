"""Localization end to end on the bus (spec §9, Table 4-1; docs/protocol.md): the v2 general
localization of Fig. 4-13 checked against the world's ground truth, and the thesis firmware's
fixed-side Localize as it is observed (spec §12).

What "right" means: localization coordinates live in the frame of the reference module (the
one ``Ref`` made X = Y = 0, Yref = 0). When the reference sits at the world's origin with
orientation 0 (the ``localization`` scenario), every module must report its world cell and
``Yref`` = its world orientation (``bus.lattice.body_to_global(side, orientation)`` is body side
+ orientation: the same convention as the receiver's ``Yref = S - j``). A reference rotated by
``o_r`` rotates the whole localization frame: a module reports its cell relative to the
reference, rotated by ``-o_r`` steps, and ``Yref = orientation - o_r (mod 6)``."""

from __future__ import annotations

import dataclasses

import pytest

from bus.codec import Kind
from bus.envelope import Envelope
from bus.functions import FunctionCode as F
from bus.lattice import Cell, rings
from bus.scenario import load, loads
from bus.timing import TICK_NS, localize_step_ticks

from fleet_rig import BOOTED_S, FleetRig

OFFSET = {1: (-1, 1), 2: (0, 1), 3: (1, 0), 4: (1, -1), 5: (0, -1), 6: (-1, 0)}  # Table 4-1


def rotate(x: int, y: int, steps: int) -> tuple[int, int]:
    """Rotate a lattice offset by ``steps`` sides (side s's offset -> side s+steps's)."""
    for _ in range(steps % 6):
        x, y = x + y, -x
    return x, y


class Rig(FleetRig):
    def __init__(self, scenario, profile: str | None = None, power: bool = True) -> None:
        super().__init__("loc", scenario, profile)
        self.side: list[Envelope] = []
        self.bus.subscribe_frames(self.side.append, "side")
        if power:
            self.boot()
            self.pc.flush()  # several modules' boot banners collided on the centre channel


@pytest.fixture
def rigs():
    made: list[Rig] = []

    def make(*a, **kw) -> Rig:
        made.append(Rig(*a, **kw))
        return made[-1]
    yield make
    for r in made:
        r.close()


# --- v2 ------------------------------------------------------------------------------------------
def report(rig: Rig, ident: int) -> dict:
    """v2 read-back: Select(1, id) (ACK), Report() (POS line, then ACK 61)."""
    pc = rig.pc
    mark = len(pc.received)
    pc.send(F.Select, 1, ident)
    pc.expect("ack", byte=F.Select, since=mark, timeout_s=3)
    mark = len(pc.received)
    pc.send(F.Report)
    pos = pc.expect("position", since=mark, timeout_s=3)
    pc.expect("ack", byte=F.Report, since=mark, timeout_s=3)
    return pos.frame.view


def hops_of(scenario) -> dict[int, int]:
    """Module id -> number of module-to-module hops from the fixed module."""
    by_cell = {m.cell: m.id for m in scenario.modules}
    return {by_cell[c]: h for c, h in rings(scenario.fixed, by_cell).items()}


def expected_position(scenario, m) -> tuple[int, int, int]:
    """(X, Y, Yref) of module spec ``m`` in the reference's frame, from the world's truth."""
    ref = scenario.fixed_module
    x, y = rotate(m.cell.x - ref.cell.x, m.cell.y - ref.cell.y, -ref.orientation)
    return x, y, (m.orientation - ref.orientation) % 6


def run_localization(rig: Rig, steps: int = 3):
    """Ref on the fixed module, then ``steps`` Localize broadcasts; after each step every
    module's POS line. Returns (reports per step, (t_start, t_end) per step)."""
    sc, pc = rig.scenario, rig.pc
    fixed = sc.fixed_module.id
    mark = len(pc.received)
    pc.send(F.Select, 1, fixed)
    pc.expect("ack", byte=F.Select, since=mark, timeout_s=3)
    ref_ack = pc.ack(F.Ref, timeout_s=5)
    assert ref_ack.frame.view["role"] == "S"
    step_ns = localize_step_ticks(sc.ir_baud) * TICK_NS
    per_step, windows = [], []
    for _ in range(steps):
        pc.send(F.Select, 0)  # everyone: a broadcast nobody acknowledges
        t_start = pc.send(F.Localize)
        rig.clock.run(until_ns=t_start + step_ns + 5 * TICK_NS)
        windows.append((t_start, rig.clock.now_ns()))
        per_step.append({m.id: report(rig, m.id) for m in sc.modules})
    return per_step, windows


def _rotated(scenario, orientations):
    sc = dataclasses.replace(scenario)
    sc.modules = [dataclasses.replace(m, orientation=o) for m, o in zip(scenario.modules, orientations)]
    return sc


CASES = {
    "fig-4-13": None,  # the scenario as shipped: every orientation 0
    "rotated-modules": (0, 1, 5, 2, 4, 3),  # reference unrotated: Yref == world orientation
    "rotated-reference": (3, 1, 5, 2, 4, 0),  # everything in the reference's frame
}


@pytest.mark.parametrize("case", list(CASES))
def test_v2_localization_of_fig_4_13_in_three_steps(rigs, case):
    sc = load("localization")
    if CASES[case] is not None:
        sc = _rotated(sc, CASES[case])
    rig = rigs(sc)
    hops = hops_of(sc)
    assert max(hops.values()) == 3
    per_step, windows = run_localization(rig, steps=3)
    for k, reports in enumerate(per_step, start=1):
        # one more ring per step: after step k exactly the modules k hops from the reference
        assert {i for i, v in reports.items() if v["localized"]} == {i for i, h in hops.items() if h <= k}
    final = per_step[-1]
    for m in sc.modules:
        v = final[m.id]
        assert (v["x"], v["y"], v["yref"]) == expected_position(sc, m), (m, v)
        assert v["id"] == m.id
        assert v["substrate"] == (m.id == sc.fixed_module.id)
        assert v["mobile"] == (m.id != sc.fixed_module.id)
        if CASES[case] is None or sc.fixed_module.orientation == 0:
            assert (v["x"], v["y"], v["yref"]) == (m.cell.x, m.cell.y, m.orientation)
    # the side link, step by step: every MSG1 goes from a module localized in an earlier step,
    # on its body side toward a module of this step's ring, with that module's coordinates and
    # the side it hears on, in the reference's frame; nothing collides on a side link
    spec = {m.id: m for m in sc.modules}
    for k, (t0, t1) in enumerate(windows, start=1):
        msgs = [e for e in rig.side if e.kind == "msg1" and t0 <= e.sim_time_ns <= t1]
        assert msgs, k
        targets = set()
        for e in msgs:
            sender = spec[int(e.src[1:].split(".")[0])]
            assert hops[sender.id] < k
            g = (e.channel - 1 + sender.orientation) % 6 + 1  # world side of that body side
            dx, dy = OFFSET[g]
            (there,) = [m for m in sc.modules if m.cell == Cell(sender.cell.x + dx, sender.cell.y + dy)]
            x, y, _ = expected_position(sc, there)
            g_ref = (g - 1 - sc.fixed_module.orientation) % 6 + 1
            assert (e.view["x"], e.view["y"], e.view["side"]) == (x, y, (g_ref + 2) % 6 + 1)
            if hops[there.id] == k:
                targets.add(there.id)
        assert targets == {i for i, h in hops.items() if h == k}
        assert not [c for c in rig.bus_events if c["kind"] == "collision" and t0 <= c["sim_time_ns"] <= t1]


def test_v2_two_steps_are_not_enough_and_a_fourth_changes_nothing(rigs):
    sc = load("localization")
    rig = rigs(sc)
    per_step, _ = run_localization(rig, steps=4)
    assert not all(v["localized"] for v in per_step[1].values())
    assert all(v["localized"] for v in per_step[2].values())
    assert per_step[3] == per_step[2]


def test_v2_step_time_is_the_slot_schedule(rigs):
    """Measured: the reference is busy for exactly one step after Localize (its ACK, in v1
    compatibility mode, comes when the 36 slots have passed), and no MSG1 leaves later."""
    sc = loads('profile = "v2"\nfixed = [0, 0]\n[[modules]]\nid = 1\ncell = [0, 0]\n'
               '[[modules]]\nid = 2\ncell = [0, 1]\n')
    rig = rigs(sc)
    mark = len(rig.pc.received)
    rig.pc.send(F.Select, 1, 1)
    rig.pc.expect("ack", byte=F.Select, since=mark, timeout_s=3)
    rig.pc.ack(F.Ref, timeout_s=5)
    mark = len(rig.pc.received)
    rig.pc.send(F.Select, 3, 2)  # both addressed: both acknowledge the Localize
    rig.pc.expect("ack", byte=F.Select, role="M", since=mark, timeout_s=3)
    rig.pc.expect("ack", byte=F.Select, role="S", since=mark, timeout_s=3)
    mark = len(rig.pc.received)
    sent = rig.pc.send(F.Localize)
    sub = rig.pc.expect("ack", byte=F.Localize, role="S", since=mark, timeout_s=30)
    step_ns = localize_step_ticks(300) * TICK_NS
    busy = sub.t_first_ns - sent - 100 * TICK_NS  # the substrate's ACK delay
    assert step_ns - TICK_NS <= busy <= step_ns + 2 * TICK_NS, busy
    last_msg1 = max(e.sim_time_ns for e in rig.side if e.kind == "msg1")
    assert sent < last_msg1 <= sent + step_ns
    v = report(rig, 2)
    assert v["localized"] and (v["x"], v["y"], v["yref"]) == (0, 1, 0)


# --- thesis-2009 -----------------------------------------------------------------------------------
THESIS_SC = ('profile = "thesis-2009"\nprogram = "model"\nfixed = [0, 0]\n'
             "[[modules]]\nid = 1\ncell = [0, 0]\n"  # the reference
             "[[modules]]\nid = 2\ncell = [0, 1]\norientation = 2\n"  # across its side 2
             "[[modules]]\nid = 3\ncell = [1, 0]\n"  # across its side 3
             "[[modules]]\nid = 4\ncell = [0, -1]\n")  # across its side 5: never served


def test_thesis_localize_serves_sides_2_and_3_with_fixed_messages(rigs):
    """thesis-2009 (spec §9, §12): the reference is powered and given Ref alone (Ref is a
    broadcast: every listener would become a reference), then the others are switched on. One
    Localize: the reference sends 6 x {side 2: (0,1) S=5 twice; side 3: (1,0) S=6 twice} and
    nothing else, whoever its neighbours are. The module on side 2 (rotated by 2) reports
    LOCALIZED, Side 5, Yref 2 and gets (0,1); the one on side 3 reports Side 6, Yref 0 but takes
    X from the tens digit: (0,0) instead of (1,0); the one on side 5 hears nothing (no report)."""
    sc = loads(THESIS_SC)
    rig = rigs(sc, power=False)
    fleet, pc = rig.fleet, rig.pc
    fleet.world.start()
    fleet.modules[1].power_up()
    rig.run_to(BOOTED_S)
    ref_ack = pc.ack(F.Ref, timeout_s=5)
    assert ref_ack.frame.view["role"] == "S"
    for i in (2, 3, 4):
        fleet.modules[i].power_up()
    rig.run_for(BOOTED_S)
    pc.flush()
    mark, side_mark = len(pc.received), len(rig.side)
    t0 = pc.send(F.Localize)
    rig.run_for(20.0)
    pc.flush()
    # the side links: exactly what the reference's fixed loop sends
    sent = [e for e in rig.side[side_mark:] if e.src == "m1.comm"]
    assert [e.kind for e in sent] == ["msg1"] * 24
    assert [(e.channel, e.view["x"], e.view["y"], e.view["side"]) for e in sent] == \
        ([(2, 0, 1, 5)] * 2 + [(3, 1, 0, 6)] * 2) * 6
    assert all(e.raw.endswith(bytes([0x2A, 0, 0, 0, 0, 0, 1, 5])) or
               e.raw.endswith(bytes([0x2A, 0, 0, 1, 0, 0, 0, 6])) for e in sent)
    assert all(e.raw.startswith(b"\n\r\n\rS: *") for e in sent)
    # the centre channel: LOCALIZED + Side + Yref from m2 and m3, nothing from m4
    got = [r.frame for r in pc.received[mark:]]
    lines = [(f.kind, f.view.get("banner") or f.view.get("value")) for f in got
             if f.kind in (Kind.BANNER, Kind.SIDE_REPORT, Kind.YREF_REPORT)]
    assert lines == [(Kind.BANNER, "LOC"), (Kind.SIDE_REPORT, 5), (Kind.YREF_REPORT, 2),
                     (Kind.BANNER, "LOC"), (Kind.SIDE_REPORT, 6), (Kind.YREF_REPORT, 0)], got
    assert not [e for e in rig.bus_events if e["kind"] == "collision" and e["sim_time_ns"] >= t0]
    # every module acknowledges (no addressing); the reference last, S=1
    acks = [(f.view["role"], f.view["byte"]) for f in got if f.kind is Kind.ACK]
    assert sorted(acks) == sorted([("M", F.Localize)] * 3 + [("S", F.Localize)])
    assert acks[-1] == ("S", F.Localize)
    # the firmware's globals (not observable on the thesis wire: the PC never learns them)
    c = {i: fleet.modules[i].comm for i in (2, 3, 4)}
    assert (c[2].L, c[2].X, c[2].Y, c[2].Yref) == (1, 0, 1, 2)
    assert (c[3].L, c[3].X, c[3].Y, c[3].Yref) == (1, 0, 0, 0)  # truth: (1, 0)
    assert (c[4].L, c[4].Yref) == (0, 1)  # nothing heard; the boot's assumed Yref = 1 stays


def test_bring_up_localizes_in_o_n_plus_d_frames(rigs):
    """Bring-up runs one Localize step per ring and reads every module back once: the PC's
    frames are Select + Ref, the reference's Select + Report, two per step and two per other
    module (O(n + d)); polling every module after every step was O(n * d)."""
    from planner_svc.bringup import BringUp

    sc = load("localization")
    rig = rigs(sc)
    sent: list[bytes] = []
    send_raw = rig.pc.send_raw

    def spy(data: bytes, **kw) -> int:
        sent.append(data)
        return send_raw(data, **kw)
    rig.pc.send_raw = spy
    said: list[str] = []
    view = BringUp(rig.pc, sc, say=said.append).run()
    n, d = len(sc.modules), max(hops_of(sc).values())
    assert len(sent) == 4 + 2 * d + 2 * (n - 1), said
    assert {i: (m.cell, m.orientation, m.localized) for i, m in view.modules.items()} == \
        {m.id: (m.cell, m.orientation, True) for m in sc.modules}
    assert f"localized {n} of {n} modules in {d} Localize step(s)" in said[-1]

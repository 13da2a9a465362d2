"""The IR medium of the world (module_sim/world.py ``_receivers``/``_on_ir``), end to end on
the bus: centre-channel collisions and the thesis substrate delay that avoids them (spec §6),
and side links that carry light only to the neighbour across the side (Table 4-1, through both
modules' orientations) whose multiplexer stays on the facing transceiver for the whole byte
(docs/protocol.md, emulation notes)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings, strategies as st

from bus import codec
from bus.functions import FunctionCode as F
from bus.ir import IrTransmitter
from bus.lattice import Cell, rule_for_step
from bus.scenario import load, loads
from bus.timing import NS_PER_S, SUBSTRATE_ACK_DELAY_TICKS, TICK_NS, byte_time_ns
from module_sim import avr
from module_sim.physics import rotation_arguments

from fleet_rig import FleetRig

TB = byte_time_ns(300)
THESIS = (8, 4, 9)
# Table 4-1, typed again here so the test does not share the world's arithmetic.
OFFSET = {1: (-1, 1), 2: (0, 1), 3: (1, 0), 4: (1, -1), 5: (0, -1), 6: (-1, 0)}


def body_side(global_side: int, orientation: int) -> int:
    """The body side of a module with this orientation (Yref) that points to ``global_side``."""
    return (global_side - 1 - orientation) % 6 + 1


def facing(global_side: int) -> int:
    return (global_side + 2) % 6 + 1


class Rig(FleetRig):
    """A booted fleet, the PC, the world's collision events and the PC's raw IR bursts."""

    def __init__(self, scenario, profile: str | None = None) -> None:
        # the Python path's medium: its ir/tx samples and the boards' UARTs are what is watched
        # (the fleet core's medium is held to it in test_core.py)
        scenario = dataclasses.replace(scenario, program=scenario.program or "model")
        super().__init__("irmed", scenario, profile)
        self.pc_bursts: list[dict] = []
        self.bus.subscribe_json(self.bus.keys.ir_rx("pc"), lambda k, d: self.pc_bursts.append(d))
        self.boot()
        self.pc.flush()  # the boot banners of several modules collided: end that noise

    def collisions(self, since_ns: int = 0, receiver: str | None = None) -> list[dict]:
        return [e for e in self.bus_events if e["kind"] == "collision" and e["sim_time_ns"] >= since_ns
                and (receiver is None or e["receiver"] == receiver)]


@pytest.fixture
def rigs():
    made: list[Rig] = []

    def make(scenario, profile: str | None = None) -> Rig:
        r = Rig(scenario, profile)
        made.append(r)
        return r
    yield make
    for r in made:
        r.close()


def select_ack(rig: Rig, mode: int, a: int = 0, *ack_roles: str) -> None:
    mark = len(rig.pc.received)
    rig.pc.send(F.Select, mode, a)
    for _ in ack_roles:
        rig.pc.expect("ack", byte=F.Select, since=mark, timeout_s=3)
        mark = len(rig.pc.received)


# --- centre channel: collisions and the substrate delay ----------------------------------------
def test_two_modules_answering_at_once_collide_and_the_pc_gets_garbage(rigs):
    """Both modules of the pair addressed (Select 1, then 3): a Report makes both send their POS
    line at the same instant. The world reports the collision at the PC with both sources and
    the AND of both lines as what the receiver got; the bursts reaching the PC are marked
    corrupt and the PC decodes neither module's POS line."""
    rig = rigs(load("pair"))
    select_ack(rig, 1, 1, "m1")
    rig.pc.send(F.Select, 3, 2)  # adds m2; m1 stays addressed: both answer (identical bytes)
    rig.run_for(1.0)
    rig.pc.flush()
    t0 = rig.clock.now_ns()
    mark, bursts = len(rig.pc.received), len(rig.pc_bursts)
    rig.pc.send(F.Report)
    rig.run_for(2.0)
    rig.pc.flush()
    lines = [codec.encode_position(i, 0, 0, 0, localized=False, mobile=True, substrate=False,
                                   role=b"M: ") for i in (1, 2)]
    anded = bytes(a & b for a, b in zip(*lines))
    assert anded not in lines
    got = rig.collisions(t0, "pc")
    assert got, rig.bus_events
    assert {tuple(e["sources"]) for e in got} == {("m1.comm", "m2.comm")}
    assert got[0]["received"] == anded.hex()  # both started at the same instant
    arrived = [b for b in rig.pc_bursts[bursts:] if b.get("type") == "burst"]
    assert {b["src"] for b in arrived} == {"m1.comm", "m2.comm"}
    # the later burst arrives garbled, the earlier one is corrected by a ``garble`` message
    assert any(any(b["corrupt"]) for b in arrived)
    assert any(b.get("type") == "garble" for b in rig.pc_bursts[bursts:])
    raws = [r.frame.raw for r in rig.pc.received[mark:]]
    assert raws and not any(line in raw for raw in raws for line in lines)
    assert not any(r.frame.kind is codec.Kind.POSITION and r.frame.view["id"] in (1, 2)
                   for r in rig.pc.received[mark:])


def test_overlapping_bytes_reach_the_receiver_once(rigs):
    """One transceiver, one UART: two lines that start at the same instant reach the PC as one
    line, the AND of both, byte for byte (here the POS lines and the ACKs of m1 and m2)."""
    rig = rigs(load("pair"))
    select_ack(rig, 1, 1, "m1")
    rig.pc.send(F.Select, 3, 2)
    rig.run_for(1.0)
    rig.pc.flush()
    mark = len(rig.pc.received)
    rig.pc.send(F.Report)
    rig.run_for(2.0)
    rig.pc.flush()
    delivered = b"".join(r.frame.raw for r in rig.pc.received[mark:])
    lines = [codec.encode_position(i, 0, 0, 0, localized=False, mobile=True, substrate=False,
                                   role=b"M: ") + codec.encode_ack(F.Report, role=b"M: ") for i in (1, 2)]
    assert delivered == bytes(a & b for a, b in zip(*lines))


def _rotation_toward_goal():
    """The pair's Table 4-3 move: mobile (1,0) about the fixed (0,0) to the goal (0,1)."""
    (rule,) = rule_for_step(Cell(1, 0), Cell(0, 1), Cell(0, 0))
    return rotation_arguments(rule, 0, 0), rule


@pytest.mark.parametrize("how", ["CW-after-Ref", "Move62"])
def test_substrate_waits_100_ticks_so_both_acks_arrive_intact(rigs, how):
    """A combined rotation frame (67/68 after Ref made m1 the substrate, or v2 Move 62 naming a
    mobile/substrate pair): the mobile acknowledges first, the substrate 100 ticks later; no
    collision at the PC and both ACK lines arrive byte for byte."""
    rig = rigs(load("pair"))
    (mi, si), rule = _rotation_toward_goal()
    cw = rule.direction.value == "CW"
    if how == "CW-after-Ref":
        select_ack(rig, 1, 1, "m1")
        rig.pc.ack(F.Ref, timeout_s=5)
        mark = len(rig.pc.received)
        rig.pc.send(F.Select, 3, 2)  # m1 (S=1) answers 100 ticks after m2: no collision either
        rig.pc.expect("ack", byte=F.Select, role="M", since=mark, timeout_s=3)
        rig.pc.expect("ack", byte=F.Select, role="S", since=mark, timeout_s=3)
        rig.run_for(0.5)
        t0, mark = rig.clock.now_ns(), len(rig.pc.received)
        rig.pc.send(F.CW if cw else F.CCW, si, *THESIS, mi, *THESIS)
        sub_role = b"S: "
    else:
        t0, mark = rig.clock.now_ns(), len(rig.pc.received)
        rig.pc.send(F.Move, 1 if cw else 2, 2, mi, 1, si, *THESIS)
        sub_role = b"M: "  # Move gives the substrate's turn without making it S=1
    mob = rig.pc.expect("ack", role="M", since=mark, timeout_s=5)
    sub = rig.pc.expect("ack", since=len(rig.pc.received), timeout_s=5)
    mcode, scode = (F.MCW, F.SCW) if cw else (F.MCCW, F.SCCW)
    assert mob.frame.raw == codec.encode_ack(mcode, role=b"M: ")
    assert sub.frame.raw == codec.encode_ack(scode, role=sub_role)
    assert sub.t_first_ns - mob.t_first_ns >= (SUBSTRATE_ACK_DELAY_TICKS - 1) * TICK_NS - 13 * TB
    assert sub.t_first_ns >= mob.t_last_ns  # one after the other
    assert rig.collisions(t0, "pc") == []
    assert [r.frame.kind for r in rig.pc.received[mark:]] == [codec.Kind.ACK, codec.Kind.ACK]


def test_without_the_substrate_delay_the_rotation_acks_collide(rigs, monkeypatch):
    """The control experiment: the same Move 62 with the 100-tick wait taken out of the comm
    board collides at the PC and neither ACK arrives intact (the delay is what saves them)."""
    import module_sim.comm_board as cb
    monkeypatch.setattr(cb, "SUBSTRATE_ACK_DELAY_TICKS", 0)
    rig = rigs(load("pair"))
    (mi, si), rule = _rotation_toward_goal()
    cw = rule.direction.value == "CW"
    t0, mark = rig.clock.now_ns(), len(rig.pc.received)
    rig.pc.send(F.Move, 1 if cw else 2, 2, mi, 1, si, *THESIS)
    rig.run_for(3.0)
    got = rig.collisions(t0, "pc")
    assert got and {tuple(e["sources"]) for e in got} == {("m1.comm", "m2.comm")}
    mcode, scode = (F.MCW, F.SCW) if cw else (F.MCCW, F.SCCW)
    raws = [r.frame.raw for r in rig.pc.received[mark:]]
    assert codec.encode_ack(mcode, role=b"M: ") not in raws
    assert codec.encode_ack(scode, role=b"M: ") not in raws


# --- side links: Table 4-1 and the multiplexer ---------------------------------------------------
@pytest.fixture
def uart1_bytes(monkeypatch):
    """Every byte that reaches a comm board's UART1 receiver: {mcu name: [(t, byte)]}."""
    seen: dict[str, list[tuple[int, int]]] = {}
    orig = avr.Uart.receive

    def receive(self, byte: int) -> None:
        if self.name == "uart1":
            seen.setdefault(self.mcu.name, []).append((self.mcu.clock.now_ns(), byte))
        orig(self, byte)
    monkeypatch.setattr(avr.Uart, "receive", receive)
    return seen


def pair_toml(g: int, o1: int, o2: int, profile: str = "v2") -> str:
    dx, dy = OFFSET[g]
    return (f'profile = "{profile}"\nfixed = [0, 0]\n'
            f"[[modules]]\nid = 1\ncell = [0, 0]\norientation = {o1}\n"
            f"[[modules]]\nid = 2\ncell = [{dx}, {dy}]\norientation = {o2}\n")


CONFIGS = [(1, 0, 0), (2, 3, 1), (3, 1, 4), (4, 5, 2), (5, 2, 5), (6, 4, 3)]  # (g, o1, o2)


@pytest.mark.parametrize("g,o1,o2", CONFIGS)
def test_side_bytes_reach_only_the_facing_transceiver(rigs, uart1_bytes, g, o1, o2):
    """m2 sits across global side g of m1. A burst m1 sends on each body side reaches m2's UART1
    only when it is m1's side toward m2 and m2's multiplexer is on m2's side facing m1 (Table
    4-1 through both orientations); every other (send side, selection) pair delivers nothing."""
    rig = rigs(loads(pair_toml(g, o1, o2)))
    m2 = rig.fleet.modules[2].comm
    s1, s2 = body_side(g, o1), body_side(facing(g), o2)
    tx = IrTransmitter(rig.bus.put, rig.bus.keys.ir_tx("m1.test"), "m1.test")
    hits = []
    for sel in range(7):
        m2.IrSel(sel)
        rig.run_for(0.05)
        for side in range(1, 7):
            before = len(uart1_bytes.get(m2.name, []))
            start = rig.clock.now_ns() + TICK_NS
            tx.send(side, b"\xff\x00", [start, start + TB], TB)
            rig.run_to((start + 3 * TB) / NS_PER_S)
            got = [b for _, b in uart1_bytes.get(m2.name, [])[before:]]
            if got:
                assert got == [0xFF, 0x00]
                hits.append((side, sel))
    assert hits == [(s1, s2)]
    m2.IrSel(0)


@pytest.mark.parametrize("g,o1,o2", [(3, 0, 0), (1, 2, 5)])
def test_irsel_and_lcircle_over_the_bus_deliver_probes_only_on_the_facing_side(rigs, uart1_bytes,
                                                                                g, o1, o2):
    """Real function codes: the PC selects m2 and sends IrSel (25) to put its multiplexer on a
    side (m2 then hears nothing from the PC), then selects m1 and sends LCircle (46), which sends
    FF then 00 on each of m1's six sides. m2 receives exactly FF 00 iff it selected the side
    facing m1; with the wrong side it receives nothing."""
    s2 = body_side(facing(g), o2)
    for sel, expected in ((s2, [0xFF, 0x00]), (s2 % 6 + 1, [])):
        rig = rigs(loads(pair_toml(g, o1, o2)))
        m2 = rig.fleet.modules[2].comm
        select_ack(rig, 1, 2, "m2")
        rig.pc.send(F.IrSel, sel)  # m2's ACK leaves on its side channel: the PC sees nothing
        rig.run_for(1.0)
        assert m2.ir_transceiver == sel
        select_ack(rig, 1, 1, "m1")
        before = len(uart1_bytes.get(m2.name, []))
        rig.pc.ack(F.LCircle, 1, 5, timeout_s=10)
        got = [b for _, b in uart1_bytes.get(m2.name, [])[before:]]
        assert got == expected, (sel, s2)
        assert rig.collisions(0, m2.name.split(".")[0]) == []


@pytest.mark.parametrize("when", ["switch-on-during-first-byte", "switch-away-during-sixth-byte"])
def test_mux_switched_during_a_byte_loses_that_byte(rigs, uart1_bytes, when):
    """A byte reaches UART1 only if the multiplexer stayed on its transceiver for the whole
    byte: switching onto the right side in the middle of byte 0 loses byte 0 (the rest of the
    frame arrives); switching away in the middle of byte 5 keeps bytes 0..4 only."""
    g, o1, o2 = 3, 1, 4
    rig = rigs(loads(pair_toml(g, o1, o2)))
    m2 = rig.fleet.modules[2].comm
    s1, s2 = body_side(g, o1), body_side(facing(g), o2)
    frame = codec.encode_command("LOn")
    wrong = s2 % 6 + 1
    m2.IrSel(wrong if when.startswith("switch-on") else s2)
    rig.run_for(0.05)
    start = rig.clock.now_ns() + TICK_NS
    starts = [start + k * TB for k in range(len(frame))]
    if when.startswith("switch-on"):
        rig.clock.call_at(start + TB // 2, m2.IrSel, s2)
        want = list(frame[1:])
    else:
        rig.clock.call_at(starts[5] + TB // 2, m2.IrSel, wrong)
        want = list(frame[:5])
    before = len(uart1_bytes.get(m2.name, []))
    IrTransmitter(rig.bus.put, rig.bus.keys.ir_tx("m1.test"), "m1.test").send(s1, frame, starts, TB)
    rig.run_to((starts[-1] + 2 * TB) / NS_PER_S)
    assert [b for _, b in uart1_bytes.get(m2.name, [])[before:]] == want


def test_a_command_frame_on_the_facing_side_is_executed_and_answered_back(rigs):
    """Bus level, both directions: a whole command frame m1 sends on its side toward m2 is
    executed by m2 when m2 listens on the facing side (LOn lights all its LEDs), and m2's ACK,
    sent on the same side, comes back to m1's facing transceiver — not to the PC."""
    g, o1, o2 = 5, 2, 1
    rig = rigs(loads(pair_toml(g, o1, o2)))
    m2 = rig.fleet.modules[2].comm
    s1, s2 = body_side(g, o1), body_side(facing(g), o2)
    back: list[dict] = []
    rig.bus.subscribe_json(rig.bus.keys.ir_rx("m1"), lambda k, d: back.append(d))
    m2.IrSel(s2)
    rig.run_for(0.05)
    mark = len(rig.pc.received)
    start = rig.clock.now_ns() + TICK_NS
    frame = codec.encode_command("LOn")
    IrTransmitter(rig.bus.put, rig.bus.keys.ir_tx("m1.test"), "m1.test").send(
        s1, frame, [start + k * TB for k in range(len(frame))], TB)
    rig.run_for(1.5)
    ack = codec.encode_ack(F.LOn, role=b"M: ")
    acks = [d for d in back if d.get("type") == "burst" and bytes.fromhex(d["data"]) == ack]
    assert len(acks) == 1 and acks[0]["rx_transceiver"] == s1 and acks[0]["src"] == "m2.comm"
    assert acks[0]["transceiver"] == s2
    assert not any(r.frame.raw == ack for r in rig.pc.received[mark:])
    leds = rig.fleet.modules[2].actuators()
    assert all(leds.led_pos) and all(leds.led_neg) and all(leds.led_joint)


def _arrived(order: list[tuple[str, bytes, list[int]]]) -> dict[tuple[str, int], int]:
    """What each byte arrives with at one receiver when ``Air`` learns of the bursts in this
    order: its value on arrival, then every ``garble`` correction."""
    from module_sim.air import Air

    air, got = Air(), {}
    for src, data, starts in order:
        values, corrupt, fixes, _ = air.collide(src, 0, data, starts, TB, now=0)
        for s, _burst, i, v in fixes:
            got[(s, i)] = v
        got.update({(src, i): v for i, v in enumerate(values)})
        air.add(src, 0, data, values, corrupt, starts, TB)
    return got


def _line_level(t: int, bursts: list[tuple[str, bytes, list[int]]]) -> int:
    """The receiver's line at ``t``, from the waveforms themselves: low (0) while any carrier
    sends a start bit or a 0 data bit (10 bit times a byte, LSB first, then the stop bit)."""
    for _src, data, starts in bursts:
        for v, s in zip(data, starts):
            if s <= t < s + TB:
                j = (t - s) * 10 // TB  # the bit time t falls in (0: start bit)
                if j == 0 or (1 <= j <= 8 and not v >> (j - 1) & 1):
                    return 0
    return 1


def _uart_reads(start: int, bursts: list[tuple[str, bytes, list[int]]]) -> int:
    """What an ATmega162 USART locked on the start bit at ``start`` reads: each data bit the
    majority of samples 8, 9 and 10 of its 16 (7/16, 8/16 and 9/16 of the bit after its edge)."""
    value = 0
    for k in range(8):
        highs = sum(_line_level(start + (16 * (k + 1) + s) * TB // 160, bursts) for s in (7, 8, 9))
        value |= (highs >= 2) << k
    return value


def _oracle(bursts: list[tuple[str, bytes, list[int]]]) -> dict[tuple[str, int], int]:
    return {(src, i): _uart_reads(s, bursts) for src, data, starts in bursts for i, s in enumerate(starts)}


def test_a_garbled_byte_is_what_the_uart_samples_of_the_and_of_the_carriers_whatever_the_order():
    """Shards hand light from another process over a lockstep window late, after later light
    of their own: a byte's value must not depend on that order. y's first byte meets x and z,
    z meets both of y's bytes but not x: each byte is what the USART samples at its own bit
    times on the line every carrier pulls low, and z keeps the bits x would clear."""
    from itertools import permutations

    x = ("m1.comm", bytes([0xF0]), [0])
    y = ("m2.comm", bytes([0xFF, 0xFF]), [TB // 2, TB // 2 + TB])
    z = ("m3.comm", bytes([0x0F]), [TB + TB // 5])
    want = _oracle([x, y, z])
    # by hand: x's 0 bits sit under y's bits 0-3 samples; y's 0xFF keeps x; z's start bit
    # lands under y0's bit 6; y1 starts under z's data, so z's high nibble of 0 clears y1's 0-3
    assert want[("m1.comm", 0)] == 0xE0 and want[("m2.comm", 0)] != 0xFF
    for order in permutations([x, y, z]):
        assert _arrived(list(order)) == want, [o[0] for o in order]


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.binary(min_size=1, max_size=4), st.integers(0, 3 * TB)),
                min_size=1, max_size=5), st.randoms(use_true_random=False))
def test_any_pile_up_in_any_order_arrives_as_the_uart_samples_it(bursts, rnd):
    """Drawn bursts from distinct transmitters (each one UART: its bytes back to back), learnt
    in a drawn order: every byte ends as the oracle's waveform sampling says."""
    drawn = [(f"m{n}.comm", data, [t0 + k * TB for k in range(len(data))])
             for n, (data, t0) in enumerate(bursts)]
    want = _oracle(drawn)
    order = list(drawn)
    rnd.shuffle(order)
    assert _arrived(order) == want


def test_the_air_forgets_light_that_has_ended():
    """A transmitter that never collides (a module's receiver hears one neighbour) for a long
    run: what the air keeps stays that of the bursts in flight, not of every burst so far."""
    from module_sim.air import Air

    air = Air()
    for n in range(2000):
        t = n * 3 * TB
        starts = [t, t + TB]
        values, corrupt, fixes, sources = air.collide("m1.comm", n, b"\x55\xaa", starts, TB, t)
        assert values == [0x55, 0xAA] and not any(corrupt) and not fixes and not sources
        air.add("m1.comm", n, b"\x55\xaa", values, corrupt, starts, TB)
    assert len(air.runs["m1.comm"][0]) <= 2 and len(air.keys) <= 4 and len(air.members) <= 4
    assert len(air.pending) <= 2 * 24 and len(air.low_a) <= 2 * 9

"""Spec §9/§12 on one module: Ref, Localize with no neighbour, the boot's orientation, and
(v2) the location report. Both profiles; a serial target runs the centre-channel checks.

A lone module has no neighbour, so nothing can localize it: what a single target shows is
Ref's effect, how long Localize keeps the module busy, and that it reports nothing."""

import pytest

from bus import codec
from bus.codec import Kind
from bus.functions import FunctionCode as F
from bus.pins import LED_NEG, LED_POS
from bus.timing import LOCALIZE_LISTEN_TICKS, SUBSTRATE_ACK_DELAY_TICKS, TICK_NS, localize_step_ticks

LYREF_TICKS = 20  # LYref: side LED positive 10 ticks, negative 10 ticks


def _fresh_only(bench, why: str) -> None:
    """Skip unless the module powered up for this test (virtual or simavr targets)."""
    if not bench.fresh:
        pytest.skip(f"{why} on {bench.target}")


def _read_end(bench, sent_end: int) -> int:
    """When the module has read the frame: the thesis comm board leaves the '#' unread."""
    return sent_end - (bench.pc.byte_ns if bench.profile == "thesis-2009" else 0)


def _ack_after(bench, pc, fn, *args, timeout_s=10.0):
    mark = len(pc.received)
    sent = pc.send(fn, *args)
    ack = pc.expect("ack", since=mark, timeout_s=timeout_s)
    return ack, ack.t_first_ns - _read_end(bench, sent), pc.received[mark:]


def test_ref_makes_a_substrate_that_answers_100_ticks_late(hexbench_bench, hexbench_pc):
    """Ref (65): M=0, S=1 -> the ACK carries "S: " and comes after Ref's three LYref flashes
    (60 ticks) plus the substrate's 100 ticks; every later ACK is an S ACK, 100 ticks late."""
    _fresh_only(hexbench_bench, "Ref cannot be undone without a power cycle (every later test's "
                  "ACK would change)")
    tol = hexbench_bench.time_tolerance_ns
    ack, waited, _ = _ack_after(hexbench_bench, hexbench_pc, F.Ref)
    assert ack.frame.raw == codec.encode_ack(F.Ref, role=b"S: ")
    ticks = 3 * LYREF_TICKS + SUBSTRATE_ACK_DELAY_TICKS
    assert (ticks - 1) * TICK_NS - tol < waited <= ticks * TICK_NS + tol, waited
    ack, waited, _ = _ack_after(hexbench_bench, hexbench_pc, F.LOn)
    assert ack.frame.raw == codec.encode_ack(F.LOn, role=b"S: ")
    delay = SUBSTRATE_ACK_DELAY_TICKS * TICK_NS
    assert delay - TICK_NS - tol < waited <= delay + tol


def test_report_after_ref(hexbench_bench, hexbench_pc):
    """v2: Ref then Report: POS id, X = Y = 0, Yref 0, flags L and S (not M). The thesis module
    does not know Report: 'N', from a substrate."""
    _fresh_only(hexbench_bench, "Ref cannot be undone without a power cycle (every later test's "
                  "ACK would change)")
    hexbench_pc.ack(F.Ref, timeout_s=10)
    mark = len(hexbench_pc.received)
    hexbench_pc.send(F.Report)
    if hexbench_bench.profile == "thesis-2009":
        ack = hexbench_pc.expect("ack", since=mark, timeout_s=10)
        assert ack.frame.raw == codec.encode_ack(ord("N"), role=b"S: ")
        return
    pos = hexbench_pc.expect("position", since=mark, timeout_s=10).frame
    assert pos.raw == codec.encode_position(hexbench_bench.module_id, 0, 0, 0, localized=True,
                                            mobile=False, substrate=True, role=b"S: ")
    assert hexbench_pc.expect("ack", since=mark, timeout_s=10).frame.view["byte"] == F.Report


def test_v2_boot_does_not_claim_a_position(hexbench_bench, hexbench_pc):
    """v2 keeps the LOCALIZED banner for v1 PCs, but L stays 0 and Yref 0 (spec §12)."""
    if hexbench_bench.profile != "v2":
        pytest.skip("the thesis module cannot report its state")
    mark = len(hexbench_pc.received)
    hexbench_pc.send(F.Report)
    v = hexbench_pc.expect("position", since=mark, timeout_s=10).frame.view
    assert (v["x"], v["y"], v["yref"], v["localized"], v["mobile"], v["substrate"]) == \
        (0, 0, 0, False, True, False)


def test_boot_orientation_shows_on_lyref(hexbench_bench, hexbench_pc):
    """LYref(0) (50) flashes the side that faces global +Y, body side 2 - Yref: side 1 on the
    thesis module (its boot assumes Yref = 1), side 2 on v2 (Yref 0 until localized)."""
    m = hexbench_bench.module
    lit = set()
    before = m.comm.on_ports

    def watch(mcu):
        for s in range(1, 7):
            pos, neg = LED_POS[s], LED_NEG[s]
            if not mcu.port[pos.port] & pos.mask or not mcu.port[neg.port] & neg.mask:
                lit.add(s)  # LEDs are active low
        if before is not None:
            before(mcu)
    m.comm.on_ports = watch
    try:
        assert hexbench_pc.ack(F.LYref, 0).frame.view["byte"] == F.LYref
    finally:
        m.comm.on_ports = before
    assert lit == ({1} if hexbench_bench.profile == "thesis-2009" else {2})


def test_localize_without_neighbours_reports_nothing(hexbench_bench, hexbench_pc):
    """A module that is not localized and has no neighbour: v2 listens on no side (its optical
    switches see nobody) and answers at once; the thesis firmware listens 150 ticks on each of
    the six sides, then runs LCircle (240 ticks). Neither prints LOCALIZED, and L stays 0."""
    tol = hexbench_bench.time_tolerance_ns
    if hexbench_bench.profile == "thesis-2009":
        _fresh_only(hexbench_bench, "the thesis Localize keeps the module busy 11.4 s")
    ack, waited, got = _ack_after(hexbench_bench, hexbench_pc, F.Localize, timeout_s=20)
    assert ack.frame.raw == codec.encode_ack(F.Localize, role=b"M: ")
    assert [r.frame.kind for r in got] == [Kind.ACK]
    if hexbench_bench.profile == "v2":
        assert waited <= TICK_NS + tol
        mark = len(hexbench_pc.received)
        hexbench_pc.send(F.Report)
        v = hexbench_pc.expect("position", since=mark, timeout_s=10).frame.view
        assert not v["localized"] and (v["x"], v["y"], v["yref"]) == (0, 0, 0)
    else:
        ticks = 6 * LOCALIZE_LISTEN_TICKS + 240
        assert (ticks - 1) * TICK_NS - tol < waited <= ticks * TICK_NS + tol, waited / TICK_NS


def test_reference_localize_alone(hexbench_bench, hexbench_pc):
    """The reference with no neighbour. v2: it keeps the whole step's 36 slots (it does not
    know nobody listens), sends nothing (no optical switch is on), stays at (0,0), Yref 0.
    Thesis: it sends MSG1 six times on sides 2 and 3 whoever is there: 24 x 15 bytes on the
    wire, (0,1) S=5 on side 2 and (1,0) S=6 on side 3. Either way no LOCALIZED line."""
    bench = hexbench_bench
    _fresh_only(bench, "Ref cannot be undone without a power cycle, and the step takes 20 s")
    tol = bench.time_tolerance_ns
    side = []
    if bench.virtual:
        bench.bus.subscribe_frames(side.append, "side")
    hexbench_pc.ack(F.Ref, timeout_s=10)
    ack, waited, got = _ack_after(bench, hexbench_pc, F.Localize, timeout_s=60)
    assert ack.frame.raw == codec.encode_ack(F.Localize, role=b"S: ")
    stray = b"".join(r.frame.raw for r in got[:-1])
    if bench.virtual:  # a burst leaves whole on the transceiver it was written to
        assert [r.frame.kind for r in got] == [Kind.ACK]
    else:  # the thesis selects the centre while the last MSG1's last bytes are on the wire
        assert got[-1].frame.kind is Kind.ACK and stray in (b"", b"\x06", b"\x00\x06"), stray
    waited -= SUBSTRATE_ACK_DELAY_TICKS * TICK_NS
    if bench.profile == "v2":
        baud = round(10 * 1_000_000_000 / hexbench_pc.byte_ns)
        step = localize_step_ticks(baud) * TICK_NS
        assert step - TICK_NS - tol < waited <= step + TICK_NS + tol, (waited, step)
        assert side == []
        mark = len(hexbench_pc.received)
        hexbench_pc.send(F.Report)
        v = hexbench_pc.expect("position", since=mark, timeout_s=10).frame.view
        assert v["localized"] and (v["x"], v["y"], v["yref"]) == (0, 0, 0)
        return
    wire = 24 * 15 * hexbench_pc.byte_ns
    # (the program runs on while its last two bytes are still on the wire)
    assert wire - 2 * hexbench_pc.byte_ns - tol < waited <= wire + 24 * 6 * TICK_NS + tol, waited
    if bench.virtual:
        assert [(e.kind, e.channel, e.view["x"], e.view["y"], e.view["side"]) for e in side] == \
            ([("msg1", 2, 0, 1, 5)] * 2 + [("msg1", 3, 1, 0, 6)] * 2) * 6

"""Spec §5: the boot banners on the centre channel, byte for byte and in time."""

from bus import codec
from bus.timing import TICK_NS, byte_time_ns

TB = byte_time_ns(300)


def test_boot_banners_are_exactly_spec_5(hexbench_bench):
    frames = [r.frame for r in hexbench_bench.boot()]
    expected = (b"\n\r\n\rM: COMM. BOARD READY\n\r" b"CTR. BOARD READY\n\r" b"CTR. LISTENING\n\r"
                b"LOCALIZED\n\r" b"COMM. LISTENING\n\r")
    assert b"".join(f.raw for f in frames) == expected
    assert [f.view["banner"] for f in frames] == ["COMM_Ready", "CTR_Ready", "CTR_LST", "LOC", "COMM_LST"]


def test_boot_banner_times_are_wire_time_plus_program_waits(hexbench_bench):
    """Each banner lasts its bytes x 10 / 300 s; the gaps are the program's waits (LFlash1,
    LCircle, LColor, and the UART0 handshake) within one timer tick."""
    if not hexbench_bench.virtual:
        import pytest
        pytest.skip("needs the power-up instant")
    b = hexbench_bench.boot()
    for r in b:
        assert r.t_last_ns - r.t_first_ns == len(r.frame.raw) * TB
    comm_ready, ctr_ready, ctr_lst, loc, comm_lst = b
    assert comm_ready.t_first_ns == 0  # power-up: LOff, IrSel(0), then the preamble
    # The program continues when the second-to-last byte of a burst is in the shift register.
    resume = lambda r: r.t_first_ns + (len(r.frame.raw) - 2) * TB  # noqa: E731

    def gap(after, before, ticks):
        g = after.t_first_ns - resume(before)
        assert (ticks - 1) * TICK_NS < g <= ticks * TICK_NS + 45_000_000, (g, ticks)

    gap(ctr_ready, comm_ready, 60)  # LFlash1(3, 10); the control board's 'R' already waits
    gap(ctr_lst, ctr_ready, 60)  # 'R'/'L' handshake on UART0 (< 45 ms) and LFlash2(3, 10)
    gap(loc, ctr_lst, 240)  # LCircle(1, 5): 6 sides x 8 waits of 5 ticks
    gap(comm_lst, loc, 180)  # LColor(3, 10)


def test_handshake_repeats_R_until_answered(hexbench_bench):
    """The control board sends 'R' every 10 ticks until the comm board answers (spec §5)."""
    if not hexbench_bench.virtual:
        import pytest
        pytest.skip("UART0 is internal to the module")
    bus, seen = hexbench_bench.bus, []
    bus.subscribe_frames(seen.append, "uart0-up")
    hexbench_bench.boot()
    signals = [env.view.get("signal") for env in seen]
    assert signals.count("R") >= 2 and "L" in signals
    assert signals.index("L") > signals.index("R")
    assert codec.HANDSHAKE_READY == b"R"

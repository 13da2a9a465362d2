"""The differential: one PC script against the Python model (virtual clock) and the C
firmware (simavr, cycle-exact). Same bytes on every stream, times within one tick."""

from __future__ import annotations


import pytest

from bus.codec import encode_command
from bus.functions import FunctionCode as F
from bus.timing import NS_PER_S, TICK_NS
from module_sim.script import Event
from toolchain import needs_avr

pytestmark = needs_avr


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_model_and_firmware_agree_on_every_function(profile):
    from hexbench.firmware import compare, default_script, differential

    script = default_script(profile)
    end = max(t for t, _ in script) / NS_PER_S + 5
    model, firmware = differential(profile, script, end)
    assert compare(model, firmware) == []
    # the script reached the module: every frame but the last (sent while a side was
    # selected) was acknowledged (v2: but for those its addressing silences), v2 reported
    # its position, the debug link saw the relays
    centre = bytes(int(e.detail, 16) for e in firmware if e.what == "ir")
    assert centre.count(b"ACK") >= (len(script) - 2 if profile == "thesis-2009" else 55)
    assert (b"POS" in centre) == (profile == "v2")
    debug = bytes(int(e.detail, 16) for e in firmware if e.what == "debug")
    assert debug.count(b"MSG") >= 20
    assert (b"ACT" in debug) == (profile == "v2")
    assert any(e.what == "irdrop" for e in firmware) and any(e.what == "irside" for e in firmware)


def test_compare_finds_a_value_a_time_and_a_length():
    from hexbench.firmware import TOLERANCE_NS, compare

    a = [Event(0, "ir", "0a"), Event(100, "ir", "0d"), Event(5, "port", "comm A e2")]
    assert compare(a, list(a)) == []
    late = [Event(0, "ir", "0a"), Event(100 + TOLERANCE_NS + 1, "ir", "0d"), a[2]]
    (d,) = compare(a, late)
    assert (d.stream, d.index) == ("ir", 1) and "(time)" in d.describe()
    other = [a[0], Event(100, "ir", "0e"), a[2]]
    (d,) = compare(a, other)
    assert "(value)" in d.describe() and "0e" in d.describe()
    (d,) = compare(a, a[:2])
    assert d.stream == "port comm A" and d.firmware is None and "(length)" in d.describe()


def test_a_firmware_that_answers_late_is_caught():
    """The tolerance is one tick: a reply two ticks late is a difference."""
    from hexbench.firmware import compare, differential

    script = [(11 * NS_PER_S, encode_command("LOn"))]
    model, firmware = differential("v2", script, 13.0)
    assert compare(model, firmware) == []
    shifted = [Event(e.t_ns + 2 * TICK_NS, e.what, e.detail) if e.t_ns > 11 * NS_PER_S else e
               for e in firmware]
    assert compare(model, shifted)


def _acks(events) -> list[int]:
    centre = bytes(int(e.detail, 16) for e in events if e.what == "ir")
    return [part[0] for part in centre.split(b"ACK")[1:]]


def _port(events, board: str, letter: str) -> int:
    """The last value a board's PORTx was written with in a log."""
    return [int(e.detail.split()[2], 16) for e in events if e.what == "port"
            and e.detail.startswith(f"{board} {letter} ")][-1]


def test_a_relay_during_selftest_is_lost_cleanly_in_both_programs():
    """Issue 50 item 2, its sequence: SelfTest, JxOpen 2 1.5 s later, then SxP 3. The
    relay that reaches the busy control board is answered '~'; SxP 3 runs (it was answered
    35, the leftover '#' of SelfTest's relay frame, and S3 stayed off)."""
    from bus.pins import MAGNET_POS
    from hexbench.firmware import compare, differential

    s = NS_PER_S
    script = [(11 * s, encode_command("SelfTest")), (int(12.5 * s), encode_command("JxOpen", 2)),
              (17 * s, encode_command("SxP", 3))]
    model, firmware = differential("v2", script, 19.0)
    assert compare(model, firmware) == []
    assert _acks(firmware) == [64, ord("~"), 11]
    s3 = MAGNET_POS[3]
    assert _port(firmware, "control", s3.port) & s3.mask


def test_a_frame_with_a_damaged_start_does_not_swallow_its_retries():
    """Issue 50 item 3, its case: a Move sent with ``--timing 8,35,42`` whose '*' was damaged,
    then sent again twice. Its arguments end in '#', '*': v2 resynchronised on the '*', took the
    retry's t2 (35) for the '#' and answered ACK 35 to every retry. A frame after a silence is
    read in step whatever its arguments: each retry runs (ACK 21, MCW)."""
    from hexbench.firmware import compare, differential

    move = encode_command("Move", 1, 1, 2, 9, 5, 8, 35, 42)
    s = NS_PER_S
    script = [(11 * s, b"+" + move[1:]), (13 * s, move), (16 * s, move)]
    model, firmware = differential("v2", script, 19.0)
    assert compare(model, firmware) == []
    assert _acks(firmware) == [F.MCW, F.MCW]


def test_id_0_is_never_an_address():
    """Issue 50 item 4: a module without an id (its DIP switches all open) is neither
    selected by ``Select 1 0`` nor ``Select 3 0`` (every module without an id, or whose id
    byte timed out, would answer at once) nor moved by a ``Move`` naming 0. A broadcast
    still reaches it."""
    from hexbench.firmware import compare, differential

    s = NS_PER_S
    script = [(11 * s, encode_command("Select", 1, 0, 0)), (13 * s, encode_command("Report")),
              (15 * s, encode_command("Select", 3, 0, 0)), (17 * s, encode_command("Report")),
              (19 * s, encode_command("Move", 1, 0, 2, 0, 5, 8, 4, 9)),
              (22 * s, encode_command("Select", 0, 0, 0)), (24 * s, encode_command("LOn"))]
    model, firmware = differential("v2", script, 26.0, module_id=0)
    assert compare(model, firmware) == []
    assert not [e for e in firmware if e.what == "ir" and e.t_ns > 11 * s]  # no ACK, no POS
    debug = bytes(int(e.detail, 16) for e in firmware if e.what == "debug" and e.t_ns > 11 * s)
    assert b"MSG" not in debug  # nothing relayed: the Move ran on neither board
    assert [e for e in firmware if e.what == "port" and e.detail.startswith("comm") and e.t_ns > 24 * s]


@pytest.mark.parametrize("command", [("JTest", 1, 0), ("MCW", 2, 0, 0, 0), ("SCCW", 4, 0, 0, 0)],
                         ids=lambda c: c[0])
def test_a_zero_tick_pulse_changes_no_bit_and_is_not_reported(command):
    """Issue 50 item 6: a command with t = 0 opens and closes its coils in one step. The
    protocol reports a step that changes the bits; this one changes none, so neither
    program sends an ACT line (the model sent an all-off one when it was the first actuator
    activity after boot). After reported changes (JxOpen 1, JxClose 1) it is silent too."""
    from hexbench.firmware import compare, differential

    s = NS_PER_S
    script = [(11 * s, encode_command(*command)), (13 * s, encode_command("JxOpen", 1)),
              (15 * s, encode_command("JxClose", 1)), (17 * s, encode_command(*command))]
    model, firmware = differential("v2", script, 19.0)
    assert compare(model, firmware) == []
    debug = bytes(int(e.detail, 16) for e in firmware if e.what == "debug" and e.t_ns > 11 * s)
    assert debug.count(b"ACT") == 2

"""Codec round trips for every frame kind, and decoding against spec §5-§9."""

import pytest
from hypothesis import given, strategies as st

from bus import codec
from bus.codec import (WALTER_BUSY, WALTER_NO_POSITION, Kind, Link, encode_walter_answer,
                       encode_walter_log, encode_walter_request, parse, walter_side_op)
from bus.functions import (FUNCTIONS, Arg, Board, Function, FunctionCode, WalterFlag, WalterOp, lookup,
                           used_codes)

byte = st.integers(0, 255)
roles = st.sampled_from([b"", b"S: ", b"M: "])


def test_issue_example_decodes_to_mcw():
    f = parse("pc", bytes.fromhex("2a15040804090000000023"))
    assert f.kind is Kind.COMMAND
    assert f.view["name"] == "MCW"
    assert f.view["args"] == {"i": 4, "t1": 8, "t2": 4, "t3": 9}
    assert f.describe() == "command MCW i=4 t1=8 t2=4 t3=9"


@given(code=st.sampled_from(used_codes("v2")), data=st.data())
def test_command_round_trip(code, data):
    fn = FUNCTIONS[code]
    args = [data.draw(st.integers(a.lo, a.hi)) for a in fn.args]
    raw = codec.encode_command(code, *args)
    assert len(raw) == 11 and raw[0] == ord("*") and raw[-1] == ord("#")
    f = parse(Link.PC, raw)
    assert f.kind is Kind.COMMAND and f.raw == raw
    assert f.view["code"] == code
    assert list(f.view["args"].values()) == args


@given(code=st.sampled_from([c for c in used_codes("v1") if c <= 24]), data=st.data())
def test_relay_round_trip(code, data):
    fn = FUNCTIONS[code]
    args = [data.draw(st.integers(a.lo, a.hi)) for a in fn.args]
    raw = codec.encode_relay(code, *args)
    assert len(raw) == 7
    assert raw[2 + len(args):6] == b"N" * (4 - len(args))  # unused arguments are 'N'
    f = parse(Link.UART0_DOWN, raw)
    assert f.kind is Kind.RELAY and list(f.view["args"].values()) == args


@given(b=byte, role=roles, pre=st.booleans())
def test_ack_round_trip(b, role, pre):
    raw = codec.encode_ack(b, role=role, preamble=pre)
    f = parse(Link.CENTRE, raw)
    assert f.kind is Kind.ACK and f.view["byte"] == b
    assert f.view["preamble"] is pre
    assert f.view["role"] == (role[:1].decode() or None)


def test_ack_meanings():
    assert parse("centre", codec.encode_ack(ord("N"))).view["meaning"] == "unknown code"
    assert parse("centre", codec.encode_ack(ord("~"))).view["meaning"] == "no echo (timeout)"
    assert parse("centre", codec.encode_ack(21)).view["meaning"] == "MCW"


@pytest.mark.parametrize("name", list(codec.BANNERS))
@pytest.mark.parametrize("role", [b"", b"M: ", b"S: "])
def test_banner_round_trip(name, role):
    raw = codec.encode_banner(name, preamble=True, role=role)
    f = parse(Link.CENTRE, raw)
    assert f.kind is Kind.BANNER and f.view["banner"] == name
    assert f.view["text"] == codec.BANNERS[name].decode()


def test_boot_banner_bytes_match_spec():
    # spec §5: preamble "\n\r\n\r", role "M: ", then the text and "\n\r"
    raw = codec.encode_banner("COMM_Ready", preamble=True, role=codec.role_prefix(True, False))
    assert raw == b"\n\r\n\rM: COMM. BOARD READY\n\r"


LIMIT = codec.COORD_LIMIT["v2"]


@given(x=st.integers(-LIMIT, LIMIT), y=st.integers(-LIMIT, LIMIT), s=st.integers(1, 6), role=roles)
def test_msg1_round_trip(x, y, s, role):
    raw = codec.encode_msg1(x, y, s, role=role)
    f = parse(Link.SIDE, raw)
    assert f.kind is Kind.MSG1
    assert (f.view["x"], f.view["y"], f.view["side"], f.view["valid"]) == (x, y, s, True)


def test_msg1_firmware_bytes():
    # Appendix A: LOCMSG1(0,0,0,0,0,1,5) announces (0,1) heard on side 5
    assert codec.encode_msg1(0, 1, 5, preamble=False) == b"*" + bytes([0, 0, 0, 0, 0, 1, 5])
    assert codec.encode_msg1(-12, 3, 6, preamble=False) == b"*" + bytes([1, 1, 2, 0, 0, 3, 6])
    # v2: the tens byte is |v| div 10, so 100..127 keep their hundreds (10, 12)
    assert codec.encode_msg1(100, -127, 4, preamble=False) == b"*" + bytes([0, 10, 0, 1, 12, 7, 4])


@pytest.mark.parametrize("v", [LIMIT + 1, -LIMIT - 1, 1000])
def test_coordinates_beyond_the_limit_are_refused_not_wrapped(v):
    """MSG1 and POS raise rather than drop a digit or wrap x + 128 (the programs check first)."""
    with pytest.raises(ValueError, match=r"-127\.\.127"):
        codec.encode_msg1(v, 0, 1)
    with pytest.raises(ValueError, match=r"-127\.\.127"):
        codec.encode_position(1, 0, v, 0, localized=True, mobile=True, substrate=False)
    tens, units = divmod(abs(v), 10)
    if tens < 256:  # a MSG1 whose bytes say more than the limit is not a cell
        assert not codec.msg1_view(b"*" + bytes([0, tens, units, 0, 0, 0, 1]))["valid"]


@given(i=st.integers(1, 255), x=st.integers(-LIMIT, LIMIT), y=st.integers(-LIMIT, LIMIT), r=st.integers(0, 5),
       loc=st.booleans(), m=st.booleans(), s=st.booleans())
def test_position_round_trip(i, x, y, r, loc, m, s):
    raw = codec.encode_position(i, x, y, r, localized=loc, mobile=m, substrate=s)
    v = parse(Link.CENTRE, raw).view
    assert (v["id"], v["x"], v["y"], v["yref"], v["localized"], v["mobile"], v["substrate"]) == \
        (i, x, y, r, loc, m, s)


@given(side=st.integers(1, 6), yref=st.integers(0, 5))
def test_localization_report_lines(side, yref):
    f = parse(Link.CENTRE, codec.encode_side_report(side))
    assert f.kind is Kind.SIDE_REPORT and f.view["value"] == side
    f = parse(Link.CENTRE, codec.encode_yref_report(yref))
    assert f.kind is Kind.YREF_REPORT and f.view["value"] == yref


@given(body=st.binary(min_size=5, max_size=5))
def test_debug_lines(body):
    raw = codec.encode_debug_msg(body)
    f = parse(Link.DEBUG, raw)
    assert f.kind is Kind.DEBUG_MSG and f.raw == raw and f.view["code"] == body[0]
    ack = codec.PREAMBLE + b"ACK" + body[:1] + codec.EOL
    assert parse(Link.DEBUG, ack).view["byte"] == body[0]


def test_handshake_and_echo():
    assert parse("uart0-up", b"R").kind is Kind.HANDSHAKE
    assert parse("uart0-up", b"L").view == {"signal": "L"}
    assert parse("uart0-up", bytes([21])).view == {"code": 21, "name": "MCW"}
    assert parse("uart0-down", b"R").kind is Kind.HANDSHAKE


def test_probe_bytes():
    assert [parse("side", bytes([b])).kind for b in (0xFF, 0x00)] == [Kind.PROBE, Kind.PROBE]


@pytest.mark.parametrize("raw,reason", [
    (b"*" + bytes(9) + b"X", "expected 0x23 end at offset 10"),
    (b"*12", "truncated command frame"),
    (b"hello", "does not start a pc frame"),
])
def test_noise_reasons(raw, reason):
    f = parse("pc", raw)
    assert f.is_noise and reason in f.view["reason"] and f.raw == raw


def test_function_table_is_complete_and_consistent():
    assert FunctionCode.MCW == 21 and lookup("mcw").code == 21 and lookup(21).name == "MCW"
    unused = [6, 7, 8, 9, 10, 19, 26, 27, 55, 69, 70, 75]
    assert FUNCTIONS[63].name == "Version" and FUNCTIONS[64].name == "SelfTest"  # ours (v2)
    # ours (v2): the distributed reconfiguration's upload, beat and debug line
    walter = (51, 52, 53, 17, 18, 54)
    assert [FUNCTIONS[c].name for c in walter] == ["WalterSetup", "WalterGoal", "WalterBeat",
                                                  "WalterLog", "STwo", "LSTwo"]
    assert all(FUNCTIONS[c].profile == "v2" for c in walter)
    assert all(not FUNCTIONS[c].used for c in unused)
    assert all(FUNCTIONS[c].board.value == "control" for c in (1, 2, 3, 4, 5, 11, 12, 13, 14, 15, 16,
                                                               20, 21, 22, 23, 24))
    assert all(FUNCTIONS[c].led_mirror for c in range(1, 25)
               if FUNCTIONS[c].used and FUNCTIONS[c].profile == "v1")
    assert FUNCTIONS[42].board.value == "reserved" and FUNCTIONS[126].board.value == "reserved"
    for f in FUNCTIONS.values():
        for m in f.led_mirror:  # every mirror names a real comm-board function
            assert lookup(m).board.value == "comm"


def test_encode_rejects_bad_arguments():
    with pytest.raises(ValueError, match="t1=300"):
        codec.encode_command("MCW", 1, 300)
    with pytest.raises(ValueError, match="expected 0..6"):
        codec.encode_command("IrSel", 9)
    with pytest.raises(KeyError, match="no function named"):
        codec.encode_command("Fly", 1)


#: A relay-frame argument whose range leaves out the relay filler 'N' (78): no function of
#: Table 3-7 has one yet, so the rule is held on a made-up function.
_SIDE_ONLY = Function(70, "SideOnly", Board.CONTROL, (Arg("side", 1, 6),))


@pytest.mark.parametrize("encode,fn,filler", [
    (codec.encode_command, FUNCTIONS[FunctionCode.Move], 0),  # `Move 0 ...`: dir 0 is no direction
    (codec.encode_command, _SIDE_ONLY, 0),
    (codec.encode_relay, _SIDE_ONLY, ord("N")),
])
def test_a_value_equal_to_the_filler_is_range_checked(encode, fn, filler):
    """The filler marks an argument left out (a keyword the caller did not give), not a value
    the range check may skip: a given argument equal to it is checked like any other."""
    values = [filler] + [a.lo for a in fn.args[1:]]
    with pytest.raises(ValueError, match=f"{fn.args[0].name}={filler}: expected"):
        encode(fn, *values)


def test_an_argument_left_out_by_keyword_is_the_filler_unchecked():
    raw = codec.encode_command("Move", mid=5)
    assert raw[2:4] == bytes([0, 5])  # dir left out: the PC frame's filler, as before


# --- v2 Walter rounds (docs/protocol.md) ------------------------------------------------------
@pytest.mark.parametrize("op", list(WalterOp))
def test_walter_side_messages_round_trip(op):
    f = parse("side", encode_walter_request(op, 7))
    assert f.kind is Kind.WALTER_REQUEST and f.view == {"op": op.name.lower(), "valid": True, "position": 7}
    f = parse("side", encode_walter_answer(op))
    assert f.kind is Kind.WALTER_ANSWER and f.view == {"op": op.name.lower(), "valid": True}


def test_a_garbled_walter_side_message_does_not_check():
    raw = bytearray(encode_walter_request(WalterOp.PIVOT_CW, 0))
    raw[2] ^= 0x10  # one bit of the complement lost
    assert parse("side", bytes(raw)).view["valid"] is False
    assert walter_side_op(bytes([0, 0xFF])) is None  # a complement that checks, but no such op


def test_walter_log_line():
    flags = WalterFlag.FREE | WalterFlag.MOVED | WalterFlag.CW
    f = parse("debug", encode_walter_log(300, flags, 4, 0))
    assert f.kind is Kind.WALTER_LOG
    assert f.view["round"] == 300 % 256 and f.view["position"] == 4 and f.view["direction"] == "CW"
    assert f.view["free"] and f.view["moved"] and not f.view["stopped"]
    unknown = parse("debug", encode_walter_log(1, 0, WALTER_NO_POSITION, 0)).view
    assert unknown["position"] is None and unknown["direction"] is None


def test_walter_busy_byte_is_a_centre_frame():
    assert parse("centre", WALTER_BUSY).kind is Kind.WALTER_BUSY

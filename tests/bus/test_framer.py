"""Streaming framers: every valid frame is recovered from garbage and any chunking."""

from hypothesis import given, strategies as st

from bus import codec
from bus.codec import GRAMMARS, Kind, Link
from bus.framer import Framer, frames
from bus.functions import FUNCTIONS, used_codes

#: every coordinate the v2 protocol carries (MSG1's tens byte reaches 12)
coords = st.integers(-codec.COORD_LIMIT["v2"], codec.COORD_LIMIT["v2"])


def _starts(link: Link) -> set[int]:
    """Bytes that can begin some frame of the link."""
    return {t.head[0] for t in GRAMMARS[link] if t.head} | (
        set(range(256)) if any(not t.head for t in GRAMMARS[link]) else set())


@st.composite
def command(draw):
    code = draw(st.sampled_from(used_codes("v2")))
    return codec.encode_command(code, *[draw(st.integers(a.lo, a.hi)) for a in FUNCTIONS[code].args])


@st.composite
def centre_frame(draw):
    role = draw(st.sampled_from([b"", b"M: ", b"S: "]))
    kind = draw(st.sampled_from(["ack", "banner", "pos", "side", "yref"]))
    if kind == "ack":
        return codec.encode_ack(draw(st.integers(0, 255)), role=role)
    if kind == "banner":
        return codec.encode_banner(draw(st.sampled_from(list(codec.BANNERS))),
                                   preamble=draw(st.booleans()), role=role)
    if kind == "pos":
        return codec.encode_position(draw(st.integers(1, 255)), draw(coords),
                                     draw(coords), draw(st.integers(0, 5)),
                                     localized=True, mobile=True, substrate=False, role=role)
    if kind == "side":
        return codec.encode_side_report(draw(st.integers(1, 6)))
    return codec.encode_yref_report(draw(st.integers(0, 5)))


@st.composite
def side_frame(draw):
    if draw(st.booleans()):
        return bytes([draw(st.sampled_from(codec.PROBE_BYTES))])
    return codec.encode_msg1(draw(coords), draw(coords),
                             draw(st.integers(1, 6)), role=draw(st.sampled_from([b"", b"S: "])))


@st.composite
def relay_frame(draw):
    code = draw(st.sampled_from([c for c in used_codes("v1") if c <= 24]))
    return codec.encode_relay(code, *[draw(st.integers(a.lo, a.hi)) for a in FUNCTIONS[code].args])


GENERATORS = {Link.PC: command(), Link.CENTRE: centre_frame(), Link.SIDE: side_frame(),
              Link.UART0_DOWN: relay_frame()}


def _stream(draw, link):
    """Frames with garbage between them; garbage holds no byte that may start a frame."""
    bad = sorted(set(range(256)) - _starts(link))
    garbage = st.lists(st.sampled_from(bad), max_size=12).map(bytes)
    items = draw(st.lists(GENERATORS[link], min_size=1, max_size=8))
    stream, expected = b"", []
    for raw in items:
        stream += draw(garbage) + raw
        expected.append(raw)
    return stream + draw(garbage), expected


def _chunks(draw, data: bytes) -> list[bytes]:
    out, i = [], 0
    while i < len(data):
        n = draw(st.integers(1, 16))
        out.append(data[i:i + n])
        i += n
    return out


@given(link=st.sampled_from(list(GENERATORS)), data=st.data())
def test_recovers_every_frame_from_garbage_in_any_chunking(link, data):
    stream, expected = _stream(data.draw, link)
    framer = Framer(link)
    got = []
    for chunk in _chunks(data.draw, stream):
        got += framer.feed(chunk)
    got += framer.flush()
    valid = [t.frame.raw for t in got if t.frame.kind is not Kind.NOISE]
    assert valid == expected
    # nothing is lost: frames and noise together are exactly the input, in order
    assert b"".join(t.frame.raw for t in got) == stream
    assert all(t.frame.view.get("reason") for t in got if t.frame.is_noise)


@given(link=st.sampled_from(list(Link)), data=st.binary(max_size=300), data2=st.data())
def test_never_raises_and_loses_nothing(link, data, data2):
    framer = Framer(link)
    got = []
    for chunk in _chunks(data2.draw, data):
        got += framer.feed(chunk)
    got += framer.flush()
    assert b"".join(t.frame.raw for t in got) == data


def test_byte_at_a_time_gives_frame_times():
    raw = codec.encode_command("SxP", 3)
    framer = Framer("pc")
    out = []
    for k, b in enumerate(raw):
        out += framer.feed(b, t_ns=1000 * k)
    assert len(out) == 1 and out[0].t_first_ns == 0 and out[0].t_last_ns == 10_000
    assert out[0].frame.view["args"] == {"i": 3}


def test_resynchronises_after_a_false_start():
    good = codec.encode_command("MCW", 4, 8, 4, 9)
    stream = b"*\x01\x02" + b"\xaa" * 8 + good
    fs = frames("pc", stream)
    assert fs[-1].raw == good and not fs[-1].is_noise
    assert all(f.is_noise for f in fs[:-1])


def test_comm_board_boot_stream():
    stream = (b"\n\r\n\rM: COMM. BOARD READY\n\r" b"CTR. BOARD READY\n\r" b"CTR. LISTENING\n\r"
              b"LOCALIZED\n\r" b"COMM. LISTENING\n\r")
    assert [f.view["banner"] for f in frames("centre", stream)] == \
        ["COMM_Ready", "CTR_Ready", "CTR_LST", "LOC", "COMM_LST"]

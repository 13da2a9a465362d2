"""Recorder.write_batch and Recorder.write_packed (the batch in bus.transport.pack_batch's bytes)
write what Recorder.write writes, sample by sample: the same file byte for byte (messages:
topic, log time, publish time, sequence, data; channels, Foxglove lines and scene updates,
counts, parts and strict-mode errors); in C (recordings.native) and in pure Python."""

from __future__ import annotations

import json
import re

import pytest
from mcap.reader import make_reader

from bus.codec import Link, encode_ack, encode_msg1, parse
from bus.envelope import Envelope
from bus.transport import _envelope_json, pack_batch
from recordings import native
from recordings.foxglove import FrameLog
from recordings.recorder import Recorder
from synthetic import run_synthetic
from toolchain import missing

FLEET = "batchtest"
ROOT = f"hexbot/{FLEET}"
START_NS = 1_700_000_000_000_000_000
WALL_NS = 1_700_000_123_000_000_000


def _odd_samples() -> list[tuple[str, bytes]]:
    """Frames that are not envelopes as the bus writes them, and what is no frame at all."""
    env = Envelope.of(parse(Link.SIDE, encode_msg1(1, 2, 3)), src="m1.comm", dst="*", sim_time_ns=5_000,
                      wall_time_ns=WALL_NS, seq=1)
    good = _envelope_json(env)
    obj = json.loads(good)
    reordered = json.dumps(dict(reversed(list(obj.items())))).encode()
    return [
        (f"{ROOT}/frame/side/m1.comm", reordered),  # fields in another order: the regex path
        (f"{ROOT}/frame/side/m1.comm", good.replace(b'"m1.comm"', b'"m1\\"x"', 1)),  # an escaped quote
        (f"{ROOT}/frame/side/m1.comm", good.replace(b'"sim_time_ns":5000', b'"sim_time_ns":123456789012345678901')),
        (f"{ROOT}/frame/side/m1.comm", good.replace(b'"sim_time_ns":5000', b'"sim_time_ns":-5')),
        (f"{ROOT}/frame/side/m1.comm", good[:-1]),  # cut short
        (f"{ROOT}/frame/side/m1.comm", good.replace(b'"kind":"msg1"', b'"kind":"noise"')),
        (f"{ROOT}/frame/side/m1.comm", good.replace(b'"raw":"', b'"raw":"zz')),  # no envelope behind the head
        (f"{ROOT}/frame/side/m1.comm", b""),
        (f"{ROOT}/frame/side/m1.comm", b"not json"),
        (f"{ROOT}/frame/side/m1.comm", b"{}"),
        (f"{ROOT}/ir/tx/m1.comm", good),  # an envelope on a key that is no frame
        (f"{ROOT}/event/m1.comm", b'{"kind":"overrun","src":"m1.comm","sim_time_ns":7000}'),
        ("frame/pc/pc", good),  # a relative topic
        (f"{ROOT}/world/actuators/m1", b"[1,2]"),
    ]


def _odd_events_and_light() -> list[tuple[str, bytes]]:
    """Events and light as the fleet writes them, and what a JSON reader takes otherwise than
    a quick look would (escapes, duplicate keys, times that are no times, nesting, non-ASCII)."""
    events = [b'{"kind":"overrun","src":"m1.comm","sim_time_ns":7000}', b'{"kind":"a\\u0062c","sim_time_ns":1}',
              b'{"kind":"x","kind":"y","sim_time_ns":5}', b'{"kind":"x","sim_time_ns":5.0}',
              b'{"kind":"x","sim_time_ns":true}', b'{"kind":"x","sim_time_ns":-3}', b'{"kind":"x","sim_time_ns":0123}',
              b'{"kind":5,"sim_time_ns":9}', b'{"sim_time_ns":9}', b'{"kind":"x","wall_time_ns":77,"sim_time_ns":8}',
              b'{"kind":"x","sim_time_ns":8, "nested":{"kind":"z","sim_time_ns":1}}',
              '{"kind":"\u00e9t\u00e9","sim_time_ns":8}'.encode(), '{"kind":"é","sim_time_ns":8}'.encode(),
              b'{"kind":"x","sim_time_ns":8}\xff', b'{"kind":"x","sim_time_ns":8} ', b"[1,2]",
              b'{"kind":"x","sim_time_ns":4611686018427387904}', b'{"kind":"x","sim_time_ns":NaN}',
              b'{"kind":"x","v":[1,{"a":[]}],"s":"q\\"uote","e":1e5,"f":-0.5}', b'{"kind":"x","sim_time_ns":9}',
              b'{"kind" : "spaced" , "sim_time_ns" : 10 }', b'{"\\u006bind":"x","sim_time_ns":11}']
    light = [b'{"src":"a","sim_time_ns":-0,"x":1}', b'{"sim_time_ns": 12 ,"a":1}', b'{"sim_time_ns":"12"}',
             b'{"wall_time_ns":5}', b'{"x":"\\"sim_time_ns\\":3}', b'{"sim_time_ns":-4}', b'{}', b"{",
             b'{"sim_time_ns":00012}']
    return [(f"{ROOT}/event/m{i % 3}.comm", e) for i, e in enumerate(events)] + \
        [(f"{ROOT}/ir/rx/m{i % 2}.comm", x) for i, x in enumerate(light)]


def _many_frames(n: int) -> list[tuple[str, bytes]]:
    frames = [(Link.SIDE, parse(Link.SIDE, encode_msg1(3, -2, 4))), (Link.CENTRE, parse(Link.CENTRE, encode_ack(21))),
              (Link.SIDE, parse(Link.SIDE, b"\x07\x07"))]
    out = []
    for i in range(n):
        link, frame = frames[i % len(frames)]
        src = f"m{i % 37}.comm"
        env = Envelope.of(frame, src=src, dst="*", sim_time_ns=1_000_000_000 + i * 999_999,
                          wall_time_ns=WALL_NS + i, seq=i)
        out.append((f"{ROOT}/frame/{link.value}/{src}", _envelope_json(env)))
    return out


@pytest.fixture(scope="module")
def samples() -> list[tuple[str, bytes]]:
    """A synthetic run's samples as the bus delivered them (frames, records, malformed), then
    odd ones, then a run of frames on many topics."""
    got: list[tuple[str, bytes]] = []
    run_synthetic(FLEET, attach=lambda bus: bus.subscribe(bus.keys.all, lambda k, p: got.append((k, p))),
                  modules=4, moves=3, filler_frames=20)
    return got + _odd_samples() + _odd_events_and_light() + _many_frames(3000) + _odd_samples() + \
        _odd_events_and_light()


def _messages(path) -> list[tuple]:
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, m.publish_time, m.sequence, m.data)
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def _channels(path) -> list[tuple]:
    with open(path, "rb") as f:
        summ = make_reader(f).get_summary()
    return [(c.id, c.topic, c.schema_id, tuple(sorted(c.metadata.items()))) for c in summ.channels.values()]


def _record(path, samples, batch: int | None, packed: bool = False, **kwargs) -> Recorder:
    rec = Recorder(path, fleet=FLEET, time_source=kwargs.pop("time_source", "sim"), start_ns=START_NS,
                   flush_interval_s=3600, argv=["test"], **kwargs)
    if batch is None:
        for key, payload in samples:
            rec.write(key, payload, receive_wall_ns=WALL_NS)
    else:
        for i in range(0, len(samples), batch):
            if packed:
                rec.write_packed(pack_batch(samples[i:i + batch]), receive_wall_ns=WALL_NS)
            else:
                rec.write_batch(samples[i:i + batch], receive_wall_ns=WALL_NS)
    rec.close()
    return rec


def _same(tmp_path, samples, batch: int, **kwargs) -> None:
    one = _record(tmp_path / "one.mcap", samples, None, **kwargs)
    for name, packed in (("many", False), ("packed", True)):
        many = _record(tmp_path / f"{name}.mcap", samples, batch, packed, **kwargs)
        assert len(one.paths) == len(many.paths)
        for a, b in zip(one.paths, many.paths):
            got, want = _messages(b), _messages(a)
            assert len(got) == len(want)
            for i, (g, w) in enumerate(zip(got, want)):
                assert g == w, f"message {i} of {a.name} ({name}): {g[:4]} != {w[:4]}"
            assert _channels(b) == _channels(a)
            assert b.read_bytes() == a.read_bytes(), f"{b.name}: not the same file"
        assert many.tally.to_dict() == one.tally.to_dict()


@pytest.fixture(params=["native", "python"])
def path_kind(request, monkeypatch):
    if request.param == "native":
        if native.lib() is None:
            missing("the native batch path (a C compiler builds it)")
    else:
        monkeypatch.setattr(native, "_lib", None)
    return request.param


@pytest.mark.parametrize("batch", [1, 7, 500])
def test_a_batch_writes_what_write_writes(tmp_path, samples, batch, path_kind):
    _same(tmp_path, samples, batch)


def test_small_chunks_split_a_frame_from_its_log_line_alike(tmp_path, samples, path_kind):
    _same(tmp_path, samples, 333, chunk_size=1500)


def test_without_foxglove_and_on_wall_time(tmp_path, samples, path_kind):
    _same(tmp_path, samples, 250, foxglove=False)
    _same(tmp_path / "wall", samples, 250, time_source="wall")


def test_rotation_cuts_the_same_parts(tmp_path, samples, path_kind):
    _same(tmp_path, samples, 100, rotate_bytes=60_000)
    _same(tmp_path / "s", samples, 100, rotate_s=0.5)


def test_strict_mode_still_decodes_every_payload(tmp_path, samples, path_kind):
    _same(tmp_path, samples, 64, strict=True)
    with open(tmp_path / "many.mcap", "rb") as f:
        topics = {ch.topic for _, ch, _ in make_reader(f).iter_messages()}
    assert "_recorder/error" in topics


def test_the_batch_path_derives_foxglove_lines_and_scene(tmp_path, samples, path_kind):
    rec = _record(tmp_path / "b.mcap", samples, 500)
    topics = [t for t, *_ in _messages(rec.paths[0])]
    assert topics.count("foxglove/log") >= rec.tally.frames - 20  # a line per frame but the odd ones
    assert "foxglove/scene" in topics
    assert rec.tally.noise_by_link["side"] >= 2


def _actuator_stream(n: int = 4000) -> list[tuple[str, bytes]]:
    """Actuator records of six modules as the fleet writes them, most repeating an earlier
    record of their module but its time (LEDs blinking, coils still), coil changes among them,
    poses placing the modules part-way, and records a careful path must see: one with a
    wall_time_ns, one on another module's key, malformed ones that share a module's coils."""
    import random

    from bus.messages import Actuators, Pose

    rng = random.Random(5)
    coils = [([False] * 6, [0] * 6), ([True] + [False] * 5, [0] * 6), ([False] * 6, [1, -1, 0, 0, 0, 0]),
             ([False] * 6, [0, 0, 2, 0, 0, 0])]
    state = {m: 0 for m in range(1, 7)}
    out: list[tuple[str, bytes]] = []
    for i in range(n):
        t = 1_000_000 + 997 * i
        m = rng.randint(1, 6)
        if i == n // 3:  # the scene learns where the modules are part-way through
            for k in range(1, 7):
                out.append((f"{ROOT}/world/pose/m{k}", Pose(f"m{k}", k, k, 0, 0, t).to_json()))
        if rng.random() < 0.08:
            state[m] = rng.randrange(len(coils))
        joints, magnets = coils[state[m]]
        led = [bool(rng.getrandbits(1)) for _ in range(2)] + [False] * 4
        a = Actuators(f"m{m}", t, list(joints), list(magnets), led, [False] * 6, [False] * 6,
                      rng.choice([0, 1, None]), {"ctrl": {"A": state[m]}, "comm": {"A": 1}})
        payload = a.to_json()
        r = rng.random()
        if r < 0.005:
            payload = payload[:-1] + b',"wall_time_ns":5}'
        elif r < 0.01:
            out.append((f"{ROOT}/world/actuators/m{m % 6 + 1}", payload))  # another module's key
            continue
        elif r < 0.015:
            payload = payload.replace(b'"led_neg"', b'"led_negative"')  # a required field missing
        elif r < 0.02:
            payload = payload.replace(b'"origin":"virtual"', b'"origin":7')  # not an Actuators
        out.append((f"{ROOT}/world/actuators/m{m}", payload))
    return out


@pytest.mark.parametrize("batch", [7, 500])
def test_actuator_records_in_a_batch_are_written_as_write_writes_them(tmp_path, batch, path_kind):
    """The C batch path writes a record Python wrote before but its time, on a channel whose
    coils are the scene's: the same messages, scene updates and tally as sample by sample."""
    stream = _actuator_stream()
    _same(tmp_path, stream, batch)
    _same(tmp_path / "nofox", stream, batch, foxglove=False)
    _same(tmp_path / "wall", stream, batch, time_source="wall")
    rec = _record(tmp_path / "count.mcap", stream, batch)
    scenes = sum(1 for t, *_ in _messages(rec.paths[0]) if t == "foxglove/scene")
    assert scenes > 20  # coil changes drawn after the poses came
    if path_kind == "native" and batch >= 16:
        assert rec._native.state.records > len(stream) // 2  # most records never reached Python


def test_packed_batches_leave_python_only_what_it_acts_on(tmp_path, monkeypatch):
    """write_packed writes frames, their Log lines, events and light in C from the first, and
    an actuator record whenever it changes no coil: Python sees a module's first record and its
    coil changes (for the scene), the malformed ones, and makes one Log line per distinct
    describe text (not one per frame)."""
    if native.lib() is None:
        missing("the native batch path (a C compiler builds it)")
    records = _actuator_stream(3000)
    frames = _many_frames(3000)
    events = [(f"{ROOT}/event/m{i % 5}.comm", b'{"kind":"uart-overrun","src":"m%d.comm","sim_time_ns":%d,"lost":82}'
               % (i % 5, 2_000_000 + i)) for i in range(300)]
    light = [(f"{ROOT}/ir/rx/pc", b'{"src":"m1.comm","burst":%d,"data":"00","type":"burst"}' % i) for i in range(300)]
    stream = [s for group in zip(records, frames, events * 10, light * 10) for s in group]
    python: list[str] = []
    lines: list[bytes] = []
    drawn_here: list[str] = []
    write_one, rest, coil_change = Recorder._write_one, FrameLog.rest, Recorder._coil_change
    monkeypatch.setattr(Recorder, "_write_one", lambda self, route, *a: (python.append(route.topic),
                                                                         write_one(self, route, *a))[1])
    monkeypatch.setattr(Recorder, "_coil_change", lambda self, key, *a: (drawn_here.append(key),
                                                                         coil_change(self, key, *a))[1])
    monkeypatch.setattr(FrameLog, "rest", lambda self, payload, key: (lines.append(payload), rest(self, payload, key))[1])
    rec = _record(tmp_path / "p.mcap", stream, 500, packed=True)
    assert rec.tally.messages == len(stream)
    assert not [t for t in python if not t.startswith("world/")]  # frames, events, light: all in C
    coil_changes, last = 0, {}
    for key, payload in records:
        obj = json.loads(payload)
        coils = (obj.get("joints_open"), obj.get("magnets"))
        coil_changes += last.get(key) != coils
        last[key] = coils
    tails = len({re.sub(rb'^.*?"sim_time_ns":\d+', b"", payload) for _, payload in records})
    acted = [t for t in python if t.startswith("world/actuators/")]
    # a module's first record, a port state no module had yet, or one of the 2 % odd ones: a
    # coil change whose bytes C knows feeds the scene without the careful path
    assert len(acted) <= 6 + tails + len(records) // 25 and len(acted) < coil_changes
    # a coil change C knows how to draw (the module's look and these coils drawn once) is C's
    assert len(drawn_here) < coil_changes // 2
    assert len(lines) == 3  # one describe text per kind of frame, every other line made in C


def test_log_lines_made_in_c_are_the_sdks_own_encoding(tmp_path):
    """The Log lines write_packed makes in C (every line but the first of each describe text)
    are what Foxglove's SDK encodes for the frame's line: short and long names (lengths over
    127 take two bytes), noise at the warning level."""
    if native.lib() is None:
        missing("the native batch path (a C compiler builds it)")
    from foxglove.messages import Log, LogLevel

    from recordings.foxglove import timestamp
    from recordings.lines import describe

    frames = [(Link.SIDE, parse(Link.SIDE, encode_msg1(3, -2, 4))), (Link.CENTRE, parse(Link.CENTRE, encode_ack(21))),
              (Link.SIDE, parse(Link.SIDE, b"\x07\x07"))]
    samples, envs = [], []
    for i, src in enumerate(["m1.comm", "m" + "7" * 60 + ".comm", "s" * 200, "a b!#$%&'()*+,-./:;<=>?@[]^_`{|}~"]):
        for j, (link, frame) in enumerate(frames):
            env = Envelope.of(frame, src=src, dst="*" if j else "d" * (40 * i), sim_time_ns=10 * i + j,
                              wall_time_ns=WALL_NS, seq=i)
            samples.append((f"{ROOT}/frame/{link.value}/m{i}.comm", _envelope_json(env)))
            envs.append(env)
    rec = _record(tmp_path / "lines.mcap", samples, 500, packed=True)
    lines = [data for topic, *_, data in _messages(rec.paths[0]) if topic == "foxglove/log"]
    assert lines == [Log(timestamp=timestamp(START_NS + env.sim_time_ns),
                         level=LogLevel.Warning if env.kind == "noise" else LogLevel.Info,
                         message=f"{env.src} → {env.dst}  {describe(env)}  [{env.raw.hex()}]",
                         name=f"{env.link}/{env.src}").encode() for env in envs]
    assert any(env.kind == "noise" for env in envs)


def test_what_c_holds_between_batches_reaches_the_file_on_a_flush(tmp_path):
    """write_packed leaves the open chunk's end in C between batches: a flush (the flush
    thread's, or one before anything Python writes) puts it in the file, so a killed recorder
    loses no more than before."""
    from recordings.reader import read_frames

    rec = Recorder(tmp_path / "held.mcap", fleet=FLEET, time_source="sim", start_ns=START_NS, flush_interval_s=3600)
    frames = _many_frames(300)
    for i in range(0, 300, 30):
        rec.write_packed(pack_batch(frames[i:i + 30]), receive_wall_ns=WALL_NS)
    rec.flush()  # no footer: read as a killed recorder's file is
    assert len(list(read_frames(tmp_path / "held.mcap"))) == 300
    rec.write(*frames[0], receive_wall_ns=WALL_NS)  # Python writes after what C held, in order
    rec.write_packed(pack_batch(frames[:5]), receive_wall_ns=WALL_NS)
    rec.close()
    assert [e.seq for e in read_frames(tmp_path / "held.mcap")] == list(range(300)) + [0] + list(range(5))

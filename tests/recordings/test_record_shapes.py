"""Records read by their shape (recordings.shapes) write what decoding them writes: a mixed
stream — frames, actuator records of several modules whose poses change in between, moves,
events, switches, light, malformed records — recorded with the shapes path (write and
write_batch, C and Python) equals, message by message, what the careful path (strict mode:
every payload decoded) writes; RecordShapes.decode is json's own dict or None; a module's
scene update encoded from its cached entity is the SDK's, byte for byte."""

from __future__ import annotations

import json
import random

import pytest

from bus.codec import Link, encode_ack, encode_msg1, parse
from bus.envelope import Envelope
from bus.messages import Actuators, Pose, WorldEvent
from bus.transport import _envelope_json
from recordings.foxglove import SceneView
from recordings.shapes import RecordShapes
from test_write_batch import WALL_NS, _channels, _messages, _record

FLEET = "batchtest"
ROOT = f"hexbot/{FLEET}"
MODULES = [f"m{i}" for i in range(6)]


def _dumps(obj) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


def _actuators(module: str, t: int, rng: random.Random) -> bytes:
    magnets = [rng.choice([0, 0, 1, -1]) for _ in range(6)]
    joints = [rng.random() < 0.2 for _ in range(6)]
    leds = [rng.random() < 0.5 for _ in range(6)]
    ports = {"ctrl": {"A": rng.randrange(4), "B": 0}, "comm": {"A": rng.randrange(2)}}
    return Actuators(module, t, joints, magnets, leds, leds[::-1], leds, rng.randrange(7), ports).to_json()


def _odd_records(t: int) -> list[tuple[str, bytes]]:
    """Records the shapes path must leave to the careful one, or read as json does."""
    good = Actuators("m1", t, [False] * 6, [1] * 6, [False] * 6, [False] * 6, [False] * 6, 0).to_json()
    return [
        (f"{ROOT}/world/actuators/m1", good.replace(b'"magnets":[1,1,1,1,1,1]', b'"magnets":[NaN,1,1,1,1,1]')),
        (f"{ROOT}/world/actuators/m1", good.replace(b'"ir_channel":0,', b"")),  # a required field missing
        (f"{ROOT}/world/actuators/m1", good[:-1] + b',"sim_time_ns":5}'),  # the time twice: the last wins
        (f"{ROOT}/world/actuators/m1", good[:-1] + b',"module":"m2"}'),  # the module twice
        (f"{ROOT}/world/actuators/m1", good[:-1] + b',"wall_time_ns":1700000000000000077}'),
        (f"{ROOT}/world/actuators/m1", good[:-1] + b",}"),  # not JSON
        (f"{ROOT}/world/actuators/m1", good.replace(b'"sim_time_ns":', b'"sim_time_ns":0')),  # a leading zero
        (f"{ROOT}/world/actuators/m1", good.replace(b'"module":"m1"', b'"module":"m1\\u0032"')),
        (f"{ROOT}/world/actuators/m1", good.replace(b'{"module":"m1",', b'{"x":{"sim_time_ns":1},"module":"m1",')),
        (f"{ROOT}/world/actuators/m1", b'{"module":"m1","sim_time_ns":%d}' % t),
        (f"{ROOT}/world/actuators/m1", b"[1,2]"),
        (f"{ROOT}/world/actuators/m1", good.replace(b'"m1"', b'"m1\xff"')),  # not UTF-8
        (f"{ROOT}/world/actuators/m1", good.replace(b'"sim_time_ns":%d' % t, b'"sim_time_ns":4611686018427387905')),
        (f"{ROOT}/event/world", b'{"kind":"collision","src":"world","sim_time_ns":%d}' % t),
        (f"{ROOT}/event/world", b'{"src":"world","sim_time_ns":%d}' % t),  # no kind
    ]


def _stream(n: int, seed: int) -> list[tuple[str, bytes]]:
    rng = random.Random(seed)
    frames = [parse(Link.SIDE, encode_msg1(3, -2, 4)), parse(Link.CENTRE, encode_ack(21))]
    tails = {m: [_actuators(m, 0, rng) for _ in range(4)] for m in MODULES}  # a few states each, repeated
    out: list[tuple[str, bytes]] = []
    for i in range(n):
        t = 1_000_000 + i * 12_345
        m = rng.choice(MODULES)
        r = rng.random()
        if r < 0.45:  # the bulk: a record whose bytes after the time repeat
            payload = rng.choice(tails[m]).replace(b'"sim_time_ns":0', b'"sim_time_ns":%d' % t, 1)
            out.append((f"{ROOT}/world/actuators/{m}", payload))
        elif r < 0.7:
            frame = frames[i % 2]
            env = Envelope.of(frame, src=f"{m}.comm", dst="*", sim_time_ns=t, wall_time_ns=WALL_NS + i, seq=i)
            out.append((f"{ROOT}/frame/{frame.link.value}/{m}.comm", _envelope_json(env)))
        elif r < 0.78:  # the module moves: its scene entity changes, the cache must follow
            pose = Pose(m, int(m[1:]), rng.randrange(-3, 4), rng.randrange(-3, 4), rng.randrange(6), t,
                        fixed=rng.random() < 0.2, kind=rng.choice(["virtual", "real"]))
            out.append((f"{ROOT}/world/pose/{m}", pose.to_json()))
        elif r < 0.83:
            out.append((f"{ROOT}/world/event", WorldEvent(rng.choice(["move-started", "move-done"]), t,
                                                          module=m).to_json()))
        elif r < 0.9:
            out.append((f"{ROOT}/event/{m}.comm", _dumps({"kind": "uart-overrun", "src": f"{m}.comm",
                                                          "sim_time_ns": t, "uart": "UART0",
                                                          "lost": rng.randrange(3)})))
        elif r < 0.95:
            out.append((f"{ROOT}/world/switches/{m}", _dumps({"module": m, "present": [rng.random() < .5] * 6,
                                                              "sim_time_ns": t, "type": "switches"})))
        else:
            out.append((f"{ROOT}/ir/rx/{m}.comm", _dumps({"dst": f"{m}.comm", "byte": rng.randrange(256),
                                                          "sim_time_ns": t, "type": "rx"})))
        if i % 97 == 0:
            out += _odd_records(t)
    return out


@pytest.fixture(scope="module")
def stream() -> list[tuple[str, bytes]]:
    return _stream(6000, seed=43)


def _equal(tmp_path, stream, batch: int | None, **kwargs) -> None:
    careful = _record(tmp_path / "careful.mcap", stream, None, strict=True, **kwargs)
    shapes = _record(tmp_path / "shapes.mcap", stream, batch, **kwargs)
    got, want = _messages(shapes.paths[0]), _messages(careful.paths[0])
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        assert g == w, f"message {i}: {g[:4]} != {w[:4]}"
    assert _channels(shapes.paths[0]) == _channels(careful.paths[0])
    assert shapes.tally.to_dict() == careful.tally.to_dict()
    topics = {t for t, *_ in want}
    assert {"foxglove/scene", "foxglove/log", "_recorder/error"} <= topics


@pytest.mark.parametrize("batch", [None, 7, 500])
def test_the_shapes_path_writes_what_decoding_writes(tmp_path, stream, batch, path_kind):
    _equal(tmp_path, stream, batch)


def test_the_shapes_path_on_wall_time_and_small_chunks(tmp_path, stream, path_kind):
    _equal(tmp_path, stream, 300, time_source="wall", chunk_size=2000)


def test_decode_is_jsons_dict_or_none():
    shapes = RecordShapes()
    rng = random.Random(7)
    payloads = [p for _, p in _stream(400, seed=1)] + [p for _, p in _odd_records(123)] + [
        b'{"x\\"sim_time_ns":5,"a":1}', b'{"sim\\u005ftime_ns":5,"sim_time_ns":7}', b'{"sim_time_ns":7 ,"a":1}',
        b'{"a":1,"sim_time_ns":7} ', b'{"sim_time_ns":7}x', b'{"sim_time_ns":-7}', b'{"sim_time_ns":7.0}',
        b'{"sim_time_ns":7,"a":Infinity}', b'\xef\xbb\xbf{"sim_time_ns":7}', b' {"sim_time_ns":7,"b":[1,{"c":2}]}']
    decoded = 0
    for payload in payloads * 2 + [p.replace(b'"sim_time_ns":', b'"sim_time_ns":%d' % rng.randrange(10**6), 1)
                                   for p in payloads]:
        got = shapes.decode(payload)
        if got is None:
            continue
        decoded += 1
        want = json.loads(payload)
        assert got == want and list(got) == list(want), payload
    assert decoded > len(payloads)


def test_a_cached_entity_is_the_sdks_encoding():
    """_update_one (the entity encoded without its timestamp once per look) against the SDK's
    SceneUpdate of the entity with it; feed_record's actuator branch against feed(Actuators)."""
    rng = random.Random(3)
    fast, typed = SceneView(), SceneView()
    for i, (key, payload) in enumerate(_stream(1500, seed=5)):
        topic = key.removeprefix(ROOT + "/")
        if not topic.startswith(("world/pose/", "world/actuators/", "world/event")):
            continue
        t = rng.choice([0, 1, 999_999_999, 1_000_000_000, 1_700_000_000_123_456_789, i * 7_919])
        try:
            obj = json.loads(payload)
        except ValueError:
            continue
        got = fast.feed_record(topic, obj, t)
        if topic.startswith("world/actuators/"):
            try:
                value = Actuators.from_dict(obj)
            except (TypeError, AttributeError):  # what feed_record lets go by
                value = None
            want = None if value is None else typed.feed(value, t)
        else:
            want = typed.feed_record(topic, obj, t)
        assert got == want
        for m in fast.modules.values():
            assert m.drawn == typed.modules[m.name].drawn
            if m.placement is not None:
                assert fast._update_one(m, t) == fast._update([fast._entity(m, t)])

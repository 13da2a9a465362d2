"""Foxglove's view of a run: the lattice as ``foxglove.SceneUpdate``, frames as ``foxglove.Log``.

Built with Foxglove's own SDK (``foxglove-sdk``: its message classes and their protobuf
schemas), so the Foxglove app's 3D and Log panels open a recording, or a live run, with no
converter. One :class:`FoxgloveView` (a :class:`SceneView` and a :class:`FrameLog`) serves both
places: the recorder
writes their messages into the MCAP file beside the bus's JSON channels
(:data:`recordings.schemas.SCENE_TOPIC`, :data:`~recordings.schemas.LOG_TOPIC`), and the
live server (:mod:`recordings.live_foxglove`) sends them over Foxglove's WebSocket protocol.

The scene, in frame ``lattice`` (the lattice plane, z up, one cell across ≈ 1): each module a
hexagonal prism at its pose in its own colour (the fixed module grey, a module in the middle
of a move yellow), its six magnets as coloured bars (red +, blue −, grey off), its joints as
spheres (orange: solenoid open), a label; the goal cells outlined in green. An update carries
the entities that changed; :meth:`SceneView.snapshot` carries all of them (the recorder
writes one when it closes, so the last scene message is the whole final state).
"""

from __future__ import annotations

import json
import re
from functools import lru_cache
from typing import Any, Iterable, Protocol

from foxglove.messages import (Color, KeyValuePair, LinePrimitive, LinePrimitiveLineType, Log, LogLevel,
                               Point3, Pose as FoxPose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive,
                               TextPrimitive, Timestamp, TriangleListPrimitive, Vector3)

from bus.codec import Kind
from bus.envelope import Envelope
from bus.lattice import Cell
from bus.messages import Actuators, PlannerState, Pose, WorldEvent

from .lines import FrameLines
from .schemas import LOG_TOPIC, SCENE_TOPIC, kind_of
from .scene import (FIXED, GOAL, JOINT_CLOSED, JOINT_INSET, JOINT_OPEN, MAGNET_COLOURS, MAGNET_INSET, MOVING,
                    Placement, module_colour, rest)

FRAME_ID = "lattice"
#: Bus keys (relative to the fleet root) the scene is drawn from.
SCENE_TOPICS = ("world/pose/", "world/actuators/", "world/event", "planner/state")
HEIGHT = 0.25  # prism height, in cell units
_NO_TURN = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
_IDENTITY = FoxPose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=_NO_TURN)


def timestamp(t_ns: int) -> Timestamp:
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def _colour(rgb: tuple[int, int, int], a: float = 1.0) -> Color:
    return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=a)


def _shade(rgb: tuple[int, int, int], f: float) -> tuple[int, int, int]:
    return (int(rgb[0] * f), int(rgb[1] * f), int(rgb[2] * f))


class _Module:
    """What the scene knows of one module."""

    __slots__ = ("name", "placement", "fixed", "real", "actuators", "moving")

    def __init__(self, name: str) -> None:
        self.name = name
        self.placement: Placement | None = None
        self.fixed = False
        self.real = False
        self.actuators: Actuators | None = None
        self.moving = False


def _drawn(m: _Module, magnets: Any, joints_open: Any) -> bool:
    """Whether ``m`` is drawn with these magnets and joints already (the scene draws only
    those of an actuator record)."""
    act = m.actuators
    return act is not None and act.magnets == magnets and act.joints_open == joints_open


class SceneView:
    """World and planner records in, encoded ``foxglove.SceneUpdate`` messages out."""

    def __init__(self) -> None:
        self.modules: dict[str, _Module] = {}
        self.goal: list[tuple[int, int]] = []

    def _module(self, name: str) -> _Module:
        m = self.modules.get(name)
        if m is None:
            m = self.modules[name] = _Module(name)
        return m

    def feed(self, value: Any, t_ns: int) -> bytes | None:
        """Take one typed record; the update it causes (None if the picture did not change)."""
        if isinstance(value, Pose):
            m = self._module(value.module)
            m.placement = rest(Cell(value.x, value.y), value.orientation)
            m.fixed, m.real, m.moving = bool(value.fixed), value.kind == "real", False
            return self._one(m, t_ns)
        if isinstance(value, Actuators):
            m = self._module(value.module)
            drawn_before = _drawn(m, value.magnets, value.joints_open)
            m.actuators = value
            if m.placement is None or drawn_before:
                return None  # LEDs and ports only: not drawn in the scene
            return self._one(m, t_ns)
        if isinstance(value, WorldEvent) and value.kind == "move-started" and value.module:
            m = self._module(value.module)
            m.moving = True
            return self._one(m, t_ns) if m.placement is not None else None
        if isinstance(value, PlannerState):
            goal = [(int(c[0]), int(c[1])) for c in value.goal]
            if goal == self.goal:
                return None
            self.goal = goal
            return self._update([self._goal(t_ns)])
        return None

    def feed_record(self, topic: str, obj: Any, t_ns: int) -> bytes | None:
        """The same from a decoded bus payload of ``topic`` (a :data:`SCENE_TOPICS` key); a
        payload that is not the record its key carries changes nothing."""
        if topic.startswith("world/actuators/") and isinstance(obj, dict):
            m = self.modules.get(obj.get("module"))  # type: ignore[arg-type]
            if m is not None and m.placement is not None and _drawn(m, obj.get("magnets"), obj.get("joints_open")):
                return None  # what feed finds without decoding it: LEDs and ports only
        try:
            value = kind_of(topic).decode(obj)
        except (ValueError, KeyError, TypeError, AttributeError):
            return None
        return self.feed(value, t_ns)

    def placed_look(self, name: str) -> tuple[Any, ...] | None:
        """What a placed module's entity shows apart from its coils (None: unknown or not placed)."""
        m = self.modules.get(name)
        return None if m is None or m.placement is None else (m.name, m.placement, m.fixed, m.real, m.moving)

    def entity_rest(self, name: str) -> bytes:
        """A placed module's entity encoded after its timestamp, as its updates carry it now."""
        return _entity_rest(_look(self.modules[name]))

    def snapshot(self, t_ns: int) -> bytes:
        """Every module and the goal, as they are now."""
        entities = [self._entity(m, t_ns) for m in self.modules.values() if m.placement is not None]
        if self.goal:
            entities.append(self._goal(t_ns))
        return self._update(entities)

    # -- entities -------------------------------------------------------------------------------------
    @staticmethod
    def _update(entities: list[SceneEntity]) -> bytes:
        return SceneUpdate(entities=entities).encode()

    def _one(self, m: _Module, t_ns: int) -> bytes:
        """The update of one module's entity, as the SDK encodes it: its fields but the
        timestamp (field 1, encoded first) are made once per distinct look of the module."""
        entity = timestamp_field(t_ns) + _entity_rest(_look(m))
        return b"\x12" + _varint(len(entity)) + entity

    def _entity(self, m: _Module, t_ns: int) -> SceneEntity:
        return _entity_of(_look(m), t_ns)

    def _goal(self, t_ns: int) -> SceneEntity:
        loops = [LinePrimitive(type=LinePrimitiveLineType.LineLoop, pose=_IDENTITY, thickness=0.03,
                               points=[Point3(x=float(x), y=float(y), z=0.005) for x, y in Cell(*c).vertices()],
                               color=_colour(GOAL)) for c in self.goal]
        return SceneEntity(timestamp=timestamp(t_ns), frame_id=FRAME_ID, id="goal", lines=loops,
                           metadata=[KeyValuePair(key="cells", value=" ".join(f"{x},{y}" for x, y in self.goal))])


#: What a module's entity shows: name, placement, fixed, real, moving, magnets, joints opened.
Look = tuple[str, Placement, bool, bool, bool, tuple[int, ...], tuple[bool, ...]]


def _look(m: _Module) -> Look:
    act = m.actuators
    assert m.placement is not None
    return (m.name, m.placement, m.fixed, m.real, m.moving, tuple(act.magnets[:6]) if act is not None else (),
            tuple(bool(o) for o in act.joints_open[:6]) if act is not None else ())


def _entity_of(look: Look, t_ns: int) -> SceneEntity:
    name, p, fixed, real, moving, magnets, opened = look
    body = MOVING if moving else FIXED if fixed else module_colour(name)
    label = name + (" fixed" if fixed else "") + (" real" if real else "") + (" moving" if moving else "")
    prism, outline, text = _body(p, body, label)
    return SceneEntity(
        timestamp=timestamp(t_ns), frame_id=FRAME_ID, id=name,
        metadata=[KeyValuePair(key="cell", value=f"{p.cell.x},{p.cell.y}"),
                  KeyValuePair(key="orientation", value=str(p.orientation)),
                  KeyValuePair(key="kind", value="real" if real else "virtual"),
                  KeyValuePair(key="fixed", value=str(fixed).lower())],
        triangles=[prism], lines=[outline, _magnets(p, magnets)], spheres=_joints(p, opened), texts=[text])


@lru_cache(maxsize=16384)
def _entity_rest(look: Look) -> bytes:
    """An entity's encoding after its timestamp: protobuf writes fields in number order, the
    timestamp is field 1, so timestamp + this is the SDK's encoding of the whole entity."""
    one = timestamp_field(1)
    encoded = SceneUpdate(entities=[_entity_of(look, 1)]).encode()
    k = 1
    while encoded[k] & 0x80:  # the entity's length (a varint) after the field tag
        k += 1
    entity = encoded[k + 1:]
    assert entity.startswith(one)
    return entity[len(one):]


# A module's parts depend on few things and repeat all run long (a resting module's magnets
# switch between a handful of states): each is built once per distinct input. Building one
# from scratch is ~200 µs of small SDK objects; a cached one is reused as it is.
@lru_cache(maxsize=4096)
def _body(p: Placement, colour: tuple[int, int, int], label: str) -> tuple[TriangleListPrimitive, LinePrimitive,
                                                                          TextPrimitive]:
    """The prism (top face as a fan, each wall as two triangles), its outline and its label."""
    top = [(float(x), float(y)) for x, y in p.outline()[:6]]
    cx, cy = (float(v) for v in p.centre())
    tris: list[Point3] = []
    for i in range(6):
        (ax, ay), (bx, by) = top[i], top[(i + 1) % 6]
        tris += [Point3(x=cx, y=cy, z=HEIGHT), Point3(x=ax, y=ay, z=HEIGHT), Point3(x=bx, y=by, z=HEIGHT)]
        tris += [Point3(x=ax, y=ay, z=0.0), Point3(x=bx, y=by, z=0.0), Point3(x=bx, y=by, z=HEIGHT),
                 Point3(x=ax, y=ay, z=0.0), Point3(x=bx, y=by, z=HEIGHT), Point3(x=ax, y=ay, z=HEIGHT)]
    z = HEIGHT + 0.01
    return (TriangleListPrimitive(pose=_IDENTITY, points=tris, color=_colour(colour)),
            LinePrimitive(type=LinePrimitiveLineType.LineLoop, pose=_IDENTITY, thickness=0.02,
                          points=[Point3(x=x, y=y, z=z) for x, y in top], color=_colour(_shade(colour, 0.5))),
            TextPrimitive(pose=FoxPose(position=Vector3(x=cx, y=cy, z=z + 0.05), orientation=_NO_TURN),
                          billboard=True, font_size=14.0, scale_invariant=True,
                          color=_colour((255, 255, 255)), text=label))


@lru_cache(maxsize=16384)
def _magnets(p: Placement, magnets: tuple[int, ...]) -> LinePrimitive:
    """S1..S6 as bars along the sides: red +, blue -, grey off, magenta both relays (a fault)."""
    states = list(magnets) + [0] * (6 - len(magnets))
    z = HEIGHT + 0.01
    bars: list[Point3] = []
    colours: list[Color] = []
    for (a, b), state in zip(p.side_segments(MAGNET_INSET), states):
        c = _colour(MAGNET_COLOURS.get(state, MAGNET_COLOURS[2]))
        bars += [Point3(x=float(a[0]), y=float(a[1]), z=z), Point3(x=float(b[0]), y=float(b[1]), z=z)]
        colours += [c, c]
    return LinePrimitive(type=LinePrimitiveLineType.LineList, pose=_IDENTITY, thickness=0.06,
                         points=bars, colors=colours)


@lru_cache(maxsize=16384)
def _joints(p: Placement, opened: tuple[bool, ...]) -> list[SpherePrimitive]:
    """J1..J6 as spheres: large and orange while the solenoid holds the joint open."""
    states = list(opened) + [False] * (6 - len(opened))
    z = HEIGHT + 0.01
    return [SpherePrimitive(pose=FoxPose(position=Vector3(x=float(j[0]), y=float(j[1]), z=z), orientation=_NO_TURN),
                            size=Vector3(x=s, y=s, z=s), color=_colour(JOINT_OPEN if o else JOINT_CLOSED))
            for j, o in zip(p.joint_points(JOINT_INSET), states) for s in [0.14 if o else 0.08]]


class LineStore(Protocol):
    """Lines kept elsewhere (the recorder's C batch path, which makes lines too): a line made
    there is the line of its frame here, and a line made here is given there."""

    def line(self, head: bytes, kind: bytes) -> bytes | None: ...

    def remember(self, head: bytes, kind: bytes, rest: bytes) -> None: ...


class FrameLog:
    """Frames in, encoded ``foxglove.Log`` messages out (one line per frame, as the replay's)."""

    def __init__(self) -> None:
        self.lines = FrameLines()
        self._seen: dict[tuple[bytes, str | None], bytes] = {}  # -> the encoded Log without its timestamp
        #: where lines are shared (by an envelope's head as Envelope.to_json writes it, and kind)
        self.shared: LineStore | None = None

    def log(self, env: Envelope, t_ns: int) -> bytes:
        level = LogLevel.Warning if env.kind == Kind.NOISE.value else LogLevel.Info
        return Log(timestamp=timestamp(t_ns), level=level, message=self.lines.line(env),
                   name=f"{env.link}/{env.src}").encode()

    def log_payload(self, payload: bytes, kind: str | None, t_ns: int) -> bytes:
        """The same from a frame's JSON as it came from the bus, decoded only the first time
        its line is seen: an envelope's fields before its times (link, src, dst, raw) and its
        kind decide the line. ``ValueError``/``KeyError``/``TypeError`` if it is no envelope.

        The recorder's hot path (a Log per frame): the SDK encodes a line's level, text and name
        once; per frame only the timestamp is encoded. Protobuf writes fields in number order and
        the timestamp is field 1, so timestamp + the rest is byte for byte the SDK's own encoding
        of the whole message (a test holds this)."""
        cut = payload.find(b',"sim_time_ns"')
        if kind is None and cut > 0:
            m = _KIND.search(payload, cut)
            kind = m.group(1).decode() if m else None
        key = (payload[:cut], kind) if cut > 0 and b'"raw":' in payload[:cut] else None
        rest = self._seen.get(key) if key is not None else None
        if rest is None:
            rest = self.rest(payload, key)
        return timestamp_field(t_ns) + rest

    #: ``(the envelope's bytes before ``,"sim_time_ns"``, its kind)`` -> :meth:`rest` (read it, then
    #: call :meth:`rest` on a miss: what the recorder's batch path does per frame).
    @property
    def seen(self) -> dict[tuple[bytes, str | None], bytes]:
        return self._seen

    def rest(self, payload: bytes, key: tuple[bytes, str | None] | None) -> bytes:
        """The encoded Log of a frame without its timestamp, remembered under ``key``
        (``ValueError``/``KeyError``/``TypeError`` if the payload is no envelope)."""
        env = Envelope.from_json(payload)
        shared = self.shared
        if shared is not None:
            head, kind = _head(env), str(env.kind).encode()
            rest = shared.line(head, kind)
            if rest is None:
                rest = self._encode(env)
                shared.remember(head, kind, rest)
        else:
            rest = self._encode(env)
        if key is not None:
            if len(self._seen) > 65536:  # a long run of ever-new frames: start over
                self._seen.clear()
            self._seen[key] = rest
        return rest

    def _encode(self, env: Envelope) -> bytes:
        return Log(level=LogLevel.Warning if env.kind == Kind.NOISE.value else LogLevel.Info,
                   message=self.lines.line(env), name=f"{env.link}/{env.src}").encode()


def _head(env: Envelope) -> bytes:
    """An envelope's bytes before ``,"sim_time_ns"`` as :meth:`Envelope.to_json` writes them."""
    return (f'{{"link":{json.dumps(env.link)},"src":{json.dumps(env.src)},"dst":{json.dumps(env.dst)},'
            f'"raw":"{env.raw.hex()}"').encode()


_KIND = re.compile(rb'"kind":"([a-z0-9_-]*)"')


def _varint(n: int) -> bytes:
    if n < 1 << 35:  # seconds since 1970 need 5 bytes, nanoseconds at most 5: unrolled (once per frame)
        if n < 1 << 14:
            return bytes((n,)) if n < 0x80 else bytes((n & 0x7F | 0x80, n >> 7))
        if n < 1 << 28:
            if n < 1 << 21:
                return bytes((n & 0x7F | 0x80, n >> 7 & 0x7F | 0x80, n >> 14))
            return bytes((n & 0x7F | 0x80, n >> 7 & 0x7F | 0x80, n >> 14 & 0x7F | 0x80, n >> 21))
        return bytes((n & 0x7F | 0x80, n >> 7 & 0x7F | 0x80, n >> 14 & 0x7F | 0x80, n >> 21 & 0x7F | 0x80, n >> 28))
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


@lru_cache(maxsize=64)
def _seconds(sec: int) -> bytes:
    return b"\x08" + _varint(sec) if sec else b""


_FIELD_1 = [bytes((0x0A, n)) for n in range(128)]  # field 1, length-delimited, length n (< 128: one byte)


def timestamp_field(t_ns: int) -> bytes:
    """Field 1 of a Foxglove message (``timestamp``, a ``google.protobuf.Timestamp``), encoded:
    what the SDK writes for ``timestamp=timestamp(t_ns)`` (zero fields are left out)."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    inner = _seconds(sec) + b"\x10" + _varint(nsec) if nsec else _seconds(sec)
    return _FIELD_1[len(inner)] + inner


def module_cells(update: Any) -> Iterable[tuple[str, tuple[int, int]]]:
    """``(module, cell)`` of every module entity in a decoded SceneUpdate (any protobuf
    decoding of it, e.g. ``mcap_protobuf.decoder``'s)."""
    for e in update.entities:
        meta = {kv.key: kv.value for kv in e.metadata}
        if "cell" in meta:
            x, y = meta["cell"].split(",")
            yield e.id, (int(x), int(y))


_UNDECODED = object()


class FoxgloveView:
    """What Foxglove's panels get from the bus's samples: the one derivation the recorder
    and the live server share."""

    def __init__(self) -> None:
        self.scene = SceneView()
        self.log = FrameLog()

    def derive(self, topic: str, payload: bytes, t_ns: int, *, obj: Any = _UNDECODED,
               kind: str | None = None) -> tuple[str, bytes] | None:
        """The derived message of one sample (``topic`` relative to the fleet), as
        ``(topic, encoded protobuf)``, or None: a frame's Log line, or the scene update a
        pose, actuator record, world event or planner state leads to. ``obj`` is the payload
        decoded already, ``kind`` the frame's kind if known. A payload that is not what its
        topic says derives nothing (its own channel keeps it as it came)."""
        if topic.startswith("frame/"):
            try:
                return LOG_TOPIC, self.log.log_payload(payload, kind, t_ns)
            except (ValueError, KeyError, TypeError):
                return None
        if topic.startswith(SCENE_TOPICS):
            if obj is _UNDECODED:
                try:
                    obj = json.loads(payload)
                except ValueError:
                    return None
            update = self.scene.feed_record(topic, obj, t_ns)
            return None if update is None else (SCENE_TOPIC, update)
        return None

"""Channel kinds of a recording: which key carries what, and its JSON Schema.

Every MCAP channel is one key expression (relative to the fleet root). Its kind
decides the schema written with it, so that tools that understand
``json``/``jsonschema`` channels (Foxglove, ``mcap cat --json``) can decode the
fields, and so that our reader can turn payloads back into typed objects.

Record schemas are derived from the dataclasses in :mod:`bus.messages` by one
generic generator (:func:`dataclass_schema`), never written by hand.
"""

from __future__ import annotations

import dataclasses
import json
import types
import typing
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Union

from bus.envelope import ENVELOPE_SCHEMA, Envelope
from bus.ir import Burst
from bus.messages import (Actuators, Energy, PlannerProgress, PlannerState, Pose, Record, RunMeta,
                          Switches, WorldEvent)

JSON_SCHEMA_DRAFT = "https://json-schema.org/draft/2020-12/schema"


# --- the generic generator ---------------------------------------------------------------
def type_schema(tp: Any) -> dict[str, Any]:
    """JSON Schema of a Python type annotation (the subset the bus records use)."""
    if tp is Any:
        return {}
    if tp is type(None):
        return {"type": "null"}
    if tp is bool:  # before int: bool is an int subclass
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if tp is bytes:
        return {"type": "string", "description": "bytes, lowercase hex"}
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (Union, types.UnionType):
        options = [type_schema(a) for a in args]
        simple = [o["type"] for o in options if set(o) == {"type"} and isinstance(o["type"], str)]
        if len(simple) == len(options):  # int | None -> {"type": ["integer", "null"]}
            return {"type": simple}
        return {"anyOf": options}
    if origin in (list, tuple, typing.Sequence):
        return {"type": "array", "items": type_schema(args[0]) if args else {}}
    if origin is dict:
        return {"type": "object", "additionalProperties": type_schema(args[1]) if args else {}}
    if dataclasses.is_dataclass(tp):
        return dataclass_schema(tp)
    return {}  # unknown annotation: accept anything rather than fail to record


def dataclass_schema(cls: type, *, title: str | None = None) -> dict[str, Any]:
    """JSON Schema of a dataclass: one property per field; fields without default are required.

    Records (subclasses of :class:`bus.messages.Record`) also get their ``type`` tag,
    which :meth:`Record.to_dict` adds.
    """
    hints = typing.get_type_hints(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    for f in dataclasses.fields(cls):
        props[f.name] = type_schema(hints[f.name])
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            required.append(f.name)
    if isinstance(cls, type) and issubclass(cls, Record) and cls.TOPIC:
        props["type"] = {"type": "string", "const": cls.TOPIC}
    return {"$schema": JSON_SCHEMA_DRAFT, "title": title or f"hexbot.{cls.__name__}",
            "type": "object", "properties": props, "required": required}


# --- channel kinds -----------------------------------------------------------------------
@dataclass(frozen=True)
class ChannelKind:
    """What a channel carries: a schema name and, if typed, the class that decodes it.

    Bus channels are JSON with a JSON Schema; the channels the recorder derives for Foxglove
    (:mod:`recordings.foxglove`) are protobuf with Foxglove's own schema (``foxglove=True``).
    """

    name: str  # schema name, "hexbot.Pose"
    schema: dict[str, Any] | None  # JSON Schema (None only for foxglove kinds)
    cls: type | None = None  # Envelope or a Record subclass
    foxglove: bool = False  # a foxglove.* protobuf message named ``name``

    @property
    def message_encoding(self) -> str:
        return "protobuf" if self.foxglove else "json"

    @property
    def schema_encoding(self) -> str:
        return "protobuf" if self.foxglove else "jsonschema"

    @property
    def schema_bytes(self) -> bytes:
        if self.foxglove:
            return _foxglove_schema(self.name)
        return json.dumps(self.schema, separators=(",", ":")).encode() if self.schema else b""

    def decode(self, obj: dict[str, Any]) -> Any:
        """A typed object (Envelope, Pose, ...) from a decoded payload; the dict if untyped."""
        if self.cls is None:
            return obj
        return self.cls.from_dict(obj)  # type: ignore[attr-defined]


def _record(cls: type[Record]) -> ChannelKind:
    return ChannelKind(f"hexbot.{cls.__name__}", dataclass_schema(cls), cls)


FRAME = ChannelKind("hexbot.Frame", ENVELOPE_SCHEMA, Envelope)
#: ``event/<src>``: errors as data (Bus.event): a kind, a source, a time, free fields.
BUS_EVENT = ChannelKind("hexbot.BusEvent", {
    "$schema": JSON_SCHEMA_DRAFT, "title": "hexbot.BusEvent", "type": "object",
    "properties": {"kind": {"type": "string"}, "src": {"type": "string"},
                   "sim_time_ns": {"type": "integer"}},
    "required": ["kind"], "additionalProperties": True})
#: Written by the recorder itself when a sample cannot be recorded as it is.
RECORDER_ERROR = ChannelKind("hexbench.RecorderError", {
    "$schema": JSON_SCHEMA_DRAFT, "title": "hexbench.RecorderError", "type": "object",
    "properties": {"key": {"type": "string"}, "topic": {"type": "string"},
                   "reason": {"type": "string", "enum": ["not-json", "missing-fields"]},
                   "detail": {"type": "string"},
                   "payload_hex": {"type": "string", "description": "the sample's bytes, lowercase hex"},
                   "wall_time_ns": {"type": "integer"}, "sim_time_ns": {"type": ["integer", "null"]}},
    "required": ["key", "reason", "payload_hex"]})
#: ``ir/tx/*`` and ``ir/rx/*``: light on the bus (:mod:`bus.ir`): a burst, or a correction of
#: earlier bursts (``garble``: a collision changed bytes; ``cut``: a multiplexer moved mid-burst).
IR_LIGHT = ChannelKind("hexbot.IrLight", {
    "$schema": JSON_SCHEMA_DRAFT, "title": "hexbot.IrLight", "oneOf": [
        {**dataclass_schema(Burst, title="burst"),
         "properties": {**dataclass_schema(Burst)["properties"], "type": {"const": "burst"}}},
        {"title": "garble", "type": "object", "required": ["type", "dst", "with", "fixes"],
         "properties": {"type": {"const": "garble"}, "dst": {"type": "string"}, "with": {"type": "string"},
                        "fixes": {"type": "array", "description": "[src, burst, byte index, new value] each",
                                  "items": {"type": "array", "minItems": 4, "maxItems": 4}}}},
        {"title": "cut", "type": "object", "required": ["type", "src", "burst", "index"],
         "properties": {"type": {"const": "cut"}, "src": {"type": "string"}, "burst": {"type": "integer"},
                        "index": {"type": "integer"}, "value": {"type": ["integer", "null"]}},
         "additionalProperties": True}]})
#: ``world/sync``: a late participant asks the world to republish poses and switches.
SYNC = ChannelKind("hexbot.Sync", {
    "$schema": JSON_SCHEMA_DRAFT, "title": "hexbot.Sync", "type": "object",
    "properties": {"from": {"type": "string"}}, "additionalProperties": True})
#: ``world/inject``: an actuator fault to apply (:mod:`bus.faults`).
INJECT = ChannelKind("hexbot.Inject", {
    "$schema": JSON_SCHEMA_DRAFT, "title": "hexbot.Inject", "type": "object",
    "properties": {"fault": {"type": "string", "description": "m<id>.S<1-6>[+|-]:off or m<id>.J<1-6>:closed"}},
    "required": ["fault"]})
#: Any other key (a foreign publisher's): any JSON value, so that every channel has a schema.
UNTYPED = ChannelKind("hexbot.Json", {"$schema": JSON_SCHEMA_DRAFT, "title": "hexbot.Json",
                                      "description": "any JSON value (a key hexbench does not define)"})
#: What the recorder derives for Foxglove (a scene of the lattice, frames as log lines).
SCENE = ChannelKind("foxglove.SceneUpdate", None, foxglove=True)
LOG = ChannelKind("foxglove.Log", None, foxglove=True)
SCENE_TOPIC = "foxglove/scene"
LOG_TOPIC = "foxglove/log"
DERIVED = {SCENE_TOPIC: SCENE, LOG_TOPIC: LOG}


@lru_cache(maxsize=None)
def _foxglove_schema(name: str) -> bytes:
    """The protobuf FileDescriptorSet Foxglove's SDK ships for one of its messages."""
    from foxglove import messages  # 50 ms to import: only when a foxglove channel is written
    return bytes(getattr(messages, name.removeprefix("foxglove.")).get_schema().data)

#: Topic of the recorder's own error records (outside the bus key space: no ``hexbot/`` prefix
#: is ever stripped to this).
RECORDER_ERROR_TOPIC = "_recorder/error"

# The contract documents the key -> payload table in bus/keys.py as prose only, so the
# machine-readable form lives here: (first key chunk, second chunk or None for any, kind).
_BY_PREFIX: tuple[tuple[str, str | None, ChannelKind], ...] = (
    ("frame", None, FRAME),
    ("world", "pose", _record(Pose)),
    ("world", "actuators", _record(Actuators)),
    ("world", "event", _record(WorldEvent)),
    ("world", "energy", _record(Energy)),
    ("world", "switches", _record(Switches)),
    ("world", "confirm", _record(Pose)),
    ("planner", "state", _record(PlannerState)),
    ("planner", "progress", _record(PlannerProgress)),
    ("world", "sync", SYNC),
    ("world", "inject", INJECT),
    ("meta", None, _record(RunMeta)),
    ("event", None, BUS_EVENT),
    ("ir", None, IR_LIGHT),
)


@lru_cache(maxsize=4096)
def kind_of(topic: str) -> ChannelKind:
    """The channel kind of a topic (a key relative to the fleet root, ``world/pose/m3``)."""
    if topic == RECORDER_ERROR_TOPIC:
        return RECORDER_ERROR
    if topic in DERIVED:
        return DERIVED[topic]
    parts = topic.split("/")
    for first, second, kind in _BY_PREFIX:
        if parts[0] == first and (second is None or (len(parts) > 1 and parts[1] == second)):
            return kind
    return UNTYPED


def frame_link(topic: str) -> str | None:
    """``frame/side/m3.comm`` -> ``side``; None for a topic that is not a frame."""
    if topic.startswith("frame/"):
        parts = topic.split("/", 2)
        return parts[1] if len(parts) > 1 else None
    return None

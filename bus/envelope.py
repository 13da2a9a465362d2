"""The frame envelope: what every participant publishes for every frame on every wire.

JSON on the wire (docs/bus.md) so that a participant in any language can join.
``raw`` travels as lowercase hex; ``view`` is the codec's decoded view.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

from .codec import Frame, Link, parse

SCHEMA_VERSION = 1


@dataclass
class Envelope:
    link: str  # a bus.codec.Link value
    src: str  # endpoint that put the bytes on the wire ("m3.comm", "pc", "hil.ttyUSB0")
    dst: str  # endpoint it is meant for ("pc", "m3.ctrl", "m4.comm", "*" for broadcast)
    raw: bytes
    sim_time_ns: int  # when the last byte completed, on the run's clock
    wall_time_ns: int  # time.time_ns() when published
    seq: int  # per-source sequence number
    kind: str = ""
    view: dict[str, Any] = field(default_factory=dict)
    first_byte_ns: int | None = None  # when the first byte started (sim time)
    origin: str = "virtual"  # "virtual", "serial" (real hardware), "replay"
    channel: int | None = None  # IR transceiver (0 centre, 1..6 body side) for IR links

    @classmethod
    def of(cls, frame: Frame, *, src: str, dst: str, sim_time_ns: int, wall_time_ns: int,
           seq: int, **extra: Any) -> "Envelope":
        return cls(frame.link.value, src, dst, frame.raw, sim_time_ns, wall_time_ns, seq,
                   frame.kind.value, frame.view, **extra)

    @property
    def frame(self) -> Frame:
        """Re-decode the raw bytes (the view in the envelope is informative only)."""
        return parse(Link(self.link), self.raw)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["raw"] = self.raw.hex()
        d["v"] = SCHEMA_VERSION
        return d

    def to_json(self) -> bytes:
        return json.dumps(self.to_dict(), separators=(",", ":")).encode()

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Envelope":
        d = dict(d)
        d.pop("v", None)
        d["raw"] = bytes.fromhex(d["raw"])
        return cls(**d)

    @classmethod
    def from_json(cls, data: bytes | str) -> "Envelope":
        return cls.from_dict(json.loads(data))


#: JSON Schema of an envelope (used by the MCAP recorder so tools decode the fields).
ENVELOPE_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "hexbot.Frame",
    "type": "object",
    "properties": {
        "v": {"type": "integer"},
        "link": {"type": "string", "enum": [link.value for link in Link]},
        "src": {"type": "string"},
        "dst": {"type": "string"},
        "raw": {"type": "string", "description": "frame bytes, lowercase hex"},
        "sim_time_ns": {"type": "integer"},
        "wall_time_ns": {"type": "integer"},
        "seq": {"type": "integer"},
        "kind": {"type": "string"},
        "view": {"type": "object"},
        "first_byte_ns": {"type": ["integer", "null"]},
        "origin": {"type": "string"},
        "channel": {"type": ["integer", "null"]},
    },
    "required": ["link", "src", "dst", "raw", "sim_time_ns", "wall_time_ns", "seq"],
}

"""``hexbench recover in.mcap out.mcap``: a complete file from a damaged or cut-short one.

A recorder killed mid-write leaves no footer, summary or index, and a torn chunk stops
mcap's own reader. This copies every message that can still be read (the tolerant scan of
:class:`recordings.reader.RecordingFile`: damaged chunks are skipped, a cut tail ends the
scan) with its schema, channel, times and sequence, and the metadata, into a new file that
mcap's writer finishes: footer, summary and index, so ``mcap``'s ``make_reader`` and
``rerun mcap check`` open it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mcap.writer import Writer

from .reader import Damage, RecordingFile, parts_of


@dataclass
class Recovered:
    """What :func:`recover` copied, and what it could not."""

    messages: int = 0
    channels: int = 0
    metadata: int = 0
    damaged: list[Damage] = field(default_factory=list)
    truncated: list[str] = field(default_factory=list)  # "path: why" of parts cut short

    @property
    def lost(self) -> bool:
        """Whether anything was lost: a damaged chunk, or a part with no footer."""
        return bool(self.damaged or self.truncated)


def recover(src: str | Path, dst: str | Path) -> Recovered:
    """Copy what ``src`` (a file, or the stem of rotated parts) still holds into ``dst``."""
    parts = parts_of(src)
    out = Recovered()
    with open(dst, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="hexbench recover")
        schemas: dict[tuple[str, str, bytes], int] = {}
        channels: dict[tuple[str, str, int], int] = {}
        for part in parts:
            rf = RecordingFile(part)
            ids: dict[str, int] = {}
            for sample in rf.samples(derived=True):
                cid = ids.get(sample.topic)
                if cid is None:
                    cid = ids[sample.topic] = _channel(writer, rf, sample.topic, schemas, channels)
                writer.add_message(cid, sample.log_time_ns, sample.data, sample.publish_time_ns,
                                   sample.sequence)
                out.messages += 1
            for name, data in rf.metadata:
                writer.add_metadata(name, data)
                out.metadata += 1
            out.damaged += rf.damaged
            if not rf.complete:
                out.truncated.append(f"{part}: {rf.error or 'no footer'}")
        out.channels = len(channels)
        writer.finish()
    return out


def _channel(writer: Writer, rf: RecordingFile, topic: str,
             schemas: dict[tuple[str, str, bytes], int], channels: dict[tuple[str, str, int], int]) -> int:
    """The new file's channel of ``topic`` (and its schema), registered once."""
    ch = next(c for c in rf.channels.values() if c.topic == topic)
    sid = 0
    schema = rf.schemas.get(ch.schema_id)
    if schema is not None:
        key = (schema.name, schema.encoding, bytes(schema.data))
        if key not in schemas:
            schemas[key] = writer.register_schema(schema.name, schema.encoding, bytes(schema.data))
        sid = schemas[key]
    key2 = (topic, ch.message_encoding, sid)
    if key2 not in channels:
        channels[key2] = writer.register_channel(topic, ch.message_encoding, sid, dict(ch.metadata))
    return channels[key2]

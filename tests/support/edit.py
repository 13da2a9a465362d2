"""Rewriting a recording: copy it message by message through a function that may change a
payload (or drop it), keeping channels, schemas, times and metadata.

Used to make "what if" recordings — e.g. a recording with one ACK byte changed, which a
``--compare`` replay must then report as exactly that frame — and to repair or trim files.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from bus.envelope import Envelope

from recordings.reader import RecordingFile, Sample, parts_of, read_metadata
from recordings.sink import McapSink

#: ``edit(sample) -> payload``: the bytes to write (``sample.data`` to keep it), or None to drop it.
Edit = Callable[[Sample], "bytes | None"]


def rewrite(src: str | Path, dst: str | Path, edit: Edit, *, compression: str = "zstd") -> int:
    """Copy recording ``src`` (all parts, truncated or not) into one file ``dst`` through
    ``edit``; returns how many messages were changed or dropped."""
    files = [RecordingFile(p) for p in parts_of(src)]
    fleet = str(read_metadata(src).get("fleet", "default"))
    changed = 0
    sink: McapSink | None = None
    try:
        sink = McapSink(Path(dst), fleet=fleet, compression=compression)
        for rf in files:
            for s in rf.samples(derived=True):
                data = edit(s)
                if data is not s.data:
                    changed += 1
                if data is not None:
                    sink.write(s.topic, data, s.log_time_ns, s.publish_time_ns)
            for name, meta in rf.metadata:
                sink.add_metadata(meta, name)
    finally:
        if sink is not None:
            sink.close()
    return changed


def change_frame(src: str | Path, dst: str | Path, pick: Callable[[Envelope], bool],
                 change: Callable[[Envelope], Envelope]) -> Envelope:
    """Copy ``src`` to ``dst`` with the first frame for which ``pick`` holds replaced by
    ``change(frame)``; returns the changed frame. ``ValueError`` if no frame was picked."""
    done: list[Envelope] = []

    def edit(s: Sample) -> bytes | None:
        if done or not s.topic.startswith("frame/"):
            return s.data
        env = Envelope.from_json(s.data)
        if not pick(env):
            return s.data
        new = change(env)
        done.append(new)
        return new.to_json()

    rewrite(src, dst, edit)
    if not done:
        raise ValueError(f"no frame in {src} matched")
    return done[0]

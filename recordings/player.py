"""Playing a recording back in time order (the role of python-can's ``can.player``).

:class:`Player` yields samples in log-time order across rotated parts; the rerun replay
consumes it. The bus replay (:mod:`hexbench.bus_replay`) schedules recorded frames on a
clock with their original timing instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Iterator

from bus.envelope import Envelope

from .reader import RecordingFile, Sample, Undecodable, parts_of, run_metadata, sim_origin

#: Log times above this are wall-clock epoch times (a live recording), not sim times:
#: 10**17 ns of sim time is over three years.
WALL_EPOCH_THRESHOLD_NS = 10**17


class Player:
    """A recording as a time-ordered stream. Loads the samples once (stable sort by log time,
    so equal times keep their recorded order, which for virtual runs is publish order)."""

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None) -> None:
        self.path = Path(path)
        files = [RecordingFile(p) for p in parts_of(path)]
        wanted = None if topics is None else list(topics)
        self._samples = sorted((s for rf in files for s in rf.samples(wanted)), key=lambda s: s.log_time_ns)
        self.metadata: dict[str, Any] = run_metadata(files)  # known once the files are scanned
        self.damaged = [d for rf in files for d in rf.damaged]  # chunks skipped, lost messages
        self.t0_ns = self._origin()

    def _origin(self) -> int:
        """Time zero of the replay timeline: the start instant of sim-time recordings (0 in
        files older than it), the first sample's time for wall-time ones (so the timeline is
        sim time either way)."""
        if self.metadata.get("log_time") == "sim":
            return sim_origin(self.metadata)
        first = self._samples[0].log_time_ns if self._samples else 0
        if self.metadata.get("log_time") == "wall" or first > WALL_EPOCH_THRESHOLD_NS:
            return first
        return 0

    def __len__(self) -> int:
        return len(self._samples)

    @property
    def duration_ns(self) -> int:
        return self._samples[-1].log_time_ns - self.t0_ns if self._samples else 0

    def samples(self) -> Iterator[Sample]:
        return iter(self._samples)

    def items(self) -> Iterator[tuple[int, Sample, Any]]:
        """``(t_ns on the replay timeline, sample, typed value or Undecodable)``."""
        for s in self._samples:
            try:
                value = s.decode()
            except (ValueError, TypeError, KeyError) as exc:
                value = Undecodable(s, f"{type(exc).__name__}: {exc}")
            yield s.log_time_ns - self.t0_ns, s, value

    def envelopes(self) -> Iterator[Envelope]:
        for _, _, v in self.items():
            if isinstance(v, Envelope):
                yield v

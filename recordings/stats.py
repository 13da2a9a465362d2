"""Counting what a recording holds: one tally, fed by the recorder as it writes and by the
reader when it scans a file (so ``hexbench info`` and the recorder agree by construction)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Mapping

from .schemas import RECORDER_ERROR_TOPIC, frame_link

#: World event kinds counted as faults by ``hexbench info``.
FAULT_KINDS = frozenset({"fault", "collision"})


#: Which field of a sample names its kind, by topic class.
_FIELD = {"frame": "kind", "event": "kind", "recorder": "reason", "world": "kind"}


@lru_cache(maxsize=8192)
def _classify(topic: str) -> tuple[str | None, str | None]:
    """(class, link) of a topic; class None for topics that are only counted per topic."""
    link = frame_link(topic)
    if link is not None:
        return "frame", link
    if topic.startswith("event/"):
        return "event", None
    if topic == RECORDER_ERROR_TOPIC:
        return "recorder", None
    if topic == "world/event":
        return "world", None
    return None, None


def kind_field(topic: str) -> str | None:
    """The field of a sample of ``topic`` that the tally counts by (None: counted per topic only)."""
    what = _classify(topic)[0]
    return None if what is None else _FIELD[what]


@dataclass
class Tally:
    """Counts per topic, per link (frames and noise), errors and faults, and the time span."""

    messages: int = 0
    by_topic: Counter[str] = field(default_factory=Counter)
    frames_by_link: Counter[str] = field(default_factory=Counter)
    noise_by_link: Counter[str] = field(default_factory=Counter)
    errors_by_kind: Counter[str] = field(default_factory=Counter)  # event/* and recorder errors
    world_events_by_kind: Counter[str] = field(default_factory=Counter)
    first_ns: int | None = None
    last_ns: int | None = None

    def add(self, topic: str, obj: Any, log_time_ns: int) -> None:
        """Count one sample; ``obj`` is its decoded JSON (None if it was not JSON)."""
        what = _classify(topic)[0]
        kind = None
        if what is not None and isinstance(obj, dict):
            kind = obj.get(_FIELD[what], "?")
        self.add_kind(topic, kind, log_time_ns, has_fields=isinstance(obj, dict))

    def add_kind(self, topic: str, kind: Any, log_time_ns: int, *, has_fields: bool = True) -> None:
        """Count one sample whose kind field (``kind_field(topic)``) is already known
        (the recorder's fast path finds it without decoding the whole payload)."""
        self.messages += 1
        self.by_topic[topic] += 1
        if self.first_ns is None or log_time_ns < self.first_ns:
            self.first_ns = log_time_ns
        if self.last_ns is None or log_time_ns > self.last_ns:
            self.last_ns = log_time_ns
        what, link = _classify(topic)
        if what is None:
            return
        if kind is None:
            kind = "?"
        if what == "frame":
            self.frames_by_link[link] += 1
            if kind == "noise":
                self.noise_by_link[link] += 1
        elif what == "event":
            self.errors_by_kind[str(kind)] += 1
        elif what == "recorder":
            self.errors_by_kind["recorder:" + str(kind)] += 1
        elif has_fields:
            self.world_events_by_kind[str(kind)] += 1

    def add_counts(self, by_topic: Mapping[str, int], noise_by_topic: Mapping[str, int] | None = None) -> None:
        """Count many samples of frame topics (``noise_by_topic``: how many were noise) and of
        topics counted per topic only: the counts :meth:`add_kind` makes of them one by one,
        but the time span (:meth:`span`)."""
        for topic, n in by_topic.items():
            what, link = _classify(topic)
            if what is not None and what != "frame":
                raise ValueError(f"{topic}: its samples are counted by kind (add_kind)")
            self.messages += n
            self.by_topic[topic] += n
            if what == "frame":
                self.frames_by_link[link] += n
        for topic, n in (noise_by_topic or {}).items():
            self.noise_by_link[_classify(topic)[1]] += n

    def add_events(self, by_topic: Mapping[str, int], by_kind: Mapping[str, int]) -> None:
        """Count many event samples (``event/*``) by topic and by kind: the counts
        :meth:`add_kind` makes of them one by one, but the time span (:meth:`span`)."""
        for topic, n in by_topic.items():
            self.messages += n
            self.by_topic[topic] += n
        for kind, n in by_kind.items():
            self.errors_by_kind[kind] += n

    def span(self, first_ns: int, last_ns: int) -> None:
        """Widen the time span to ``[first_ns, last_ns]``."""
        if self.first_ns is None or first_ns < self.first_ns:
            self.first_ns = first_ns
        if self.last_ns is None or last_ns > self.last_ns:
            self.last_ns = last_ns

    def merge(self, other: "Tally") -> None:
        """Add another tally's counts (rotated parts into the whole)."""
        self.messages += other.messages
        for mine, theirs in ((self.by_topic, other.by_topic), (self.frames_by_link, other.frames_by_link),
                             (self.noise_by_link, other.noise_by_link), (self.errors_by_kind, other.errors_by_kind),
                             (self.world_events_by_kind, other.world_events_by_kind)):
            mine.update(theirs)
        for t in (other.first_ns, other.last_ns):
            if t is not None:
                self.first_ns = t if self.first_ns is None else min(self.first_ns, t)
                self.last_ns = t if self.last_ns is None else max(self.last_ns, t)

    # -- derived figures ---------------------------------------------------------------------
    @property
    def frames(self) -> int:
        return sum(self.frames_by_link.values())

    @property
    def noise(self) -> int:
        return sum(self.noise_by_link.values())

    @property
    def errors(self) -> int:
        return sum(self.errors_by_kind.values())

    @property
    def faults(self) -> int:
        return sum(n for k, n in self.world_events_by_kind.items() if k in FAULT_KINDS)

    @property
    def duration_ns(self) -> int:
        return 0 if self.first_ns is None or self.last_ns is None else self.last_ns - self.first_ns

    def to_dict(self) -> dict[str, Any]:
        return {"messages": self.messages, "frames": self.frames, "noise": self.noise,
                "errors": self.errors, "faults": self.faults,
                "first_ns": self.first_ns, "last_ns": self.last_ns,
                "frames_by_link": dict(sorted(self.frames_by_link.items())),
                "noise_by_link": dict(sorted(self.noise_by_link.items())),
                "errors_by_kind": dict(sorted(self.errors_by_kind.items())),
                "world_events_by_kind": dict(sorted(self.world_events_by_kind.items())),
                "by_topic": dict(sorted(self.by_topic.items()))}

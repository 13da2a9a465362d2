"""Replay and compare: rebuild a recorded virtual run, replay some of its links into it, and
find the first frame where the new run departs from the recording.

The new run is the recording's scenario, profile and seed (its metadata, :mod:`recordings.meta`)
as a :class:`hexbench.virtual_run.VirtualRun` on a virtual clock. The frames of the replayed
links (by default the PC's commands) are sent at their recorded sim times through
:class:`hexbench.bus_replay.BusReplay`; the frames of every other link are compared, in
order, with the recorded ones: link, source, destination, channel, sim time and bytes. The
comparison stops at the first difference. Frames the new run makes at the very instant the
recording ends are not counted against it (the recorder stopped somewhere inside that instant).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from bus.envelope import Envelope
from recordings.reader import iter_samples, read_frames, read_metadata, sim_origin

from .bus_replay import LINKS, BusReplay, parse_links
from .virtual_run import VirtualRun, resolve_scenario


class CompareError(ValueError):
    """The recording cannot be compared (no scenario, wall-clock log times...)."""


def _identity(e: Envelope) -> tuple[Any, ...]:
    return (e.link, e.src, e.dst, e.channel, e.sim_time_ns, e.raw)


def describe_frame(e: Envelope) -> str:
    """One line: ``centre m2.comm → pc ch0 t=10.614583315 s 0a0d…  (ack …)``."""
    try:
        what = e.frame.describe()
    except (KeyError, ValueError, TypeError):
        what = e.kind or "?"
    ch = "" if e.channel is None else f" ch{e.channel}"
    return f"{e.link} {e.src} → {e.dst}{ch} t={e.sim_time_ns / 1e9:.9f} s {e.raw.hex()}  ({what})"


@dataclass(frozen=True)
class Divergence:
    """The first compared frame that differs (``got`` None: the new run made no such frame;
    ``expected`` None: the new run made a frame the recording does not have)."""

    index: int  # 0-based, among the compared frames
    expected: Envelope | None
    got: Envelope | None

    @property
    def frame(self) -> Envelope:
        """The recorded frame the divergence is at (or the new run's extra one)."""
        return self.expected if self.expected is not None else self.got  # type: ignore[return-value]

    def report(self, total: int) -> str:
        f = self.frame
        lines = [f"first divergence at compared frame {self.index + 1} of {total}: link {f.link}, "
                 f"source {f.src}, sim time {f.sim_time_ns} ns",
                 f"  expected: {describe_frame(self.expected) if self.expected else '(no frame: the recording has no more)'}",
                 f"  got:      {describe_frame(self.got) if self.got else '(no frame: the new run made no more)'}"]
        return "\n".join(lines)


@dataclass
class CompareResult:
    """What :func:`compare` found."""

    path: Path
    replayed_links: tuple[str, ...]
    compared_links: tuple[str, ...]
    replayed: int  # frames replayed into the new run
    expected: int  # recorded frames on the compared links
    matched: int  # of those, how many the new run reproduced before any divergence
    end_ns: int  # the recording's last log time: the new run ran until then
    divergence: Divergence | None = None
    trailing: int = 0  # frames the new run made at the recording's last instant, beyond it

    @property
    def ok(self) -> bool:
        return self.divergence is None

    def report(self) -> str:
        head = (f"{self.path}: replayed {self.replayed} frame(s) on {', '.join(self.replayed_links)}; "
                f"compared {', '.join(self.compared_links) or 'no links'} up to {self.end_ns / 1e9:.9f} s")
        if self.divergence is None:
            return f"{head}\nno divergence: all {self.expected} recorded frames reproduced, byte for byte"
        return f"{head}\n{self.divergence.report(self.expected)}"


class _Comparator:
    """Compares the new run's frames, as they are handled, with the recorded ones."""

    def __init__(self, expected: list[Envelope], links: frozenset[str], end_ns: int) -> None:
        self.expected = expected
        self.links = links
        self.end_ns = end_ns
        self.matched = 0
        self.trailing = 0
        self.divergence: Divergence | None = None

    def on_frame(self, got: Envelope) -> None:
        if self.divergence is not None:
            return
        if got.link not in self.links:
            return
        i = self.matched
        if i >= len(self.expected):
            if got.sim_time_ns >= self.end_ns:
                self.trailing += 1
            else:
                self.divergence = Divergence(i, None, got)
            return
        if _identity(got) == _identity(self.expected[i]):
            self.matched += 1
        else:
            self.divergence = Divergence(i, self.expected[i], got)

    def finish(self) -> None:
        if self.divergence is None and self.matched < len(self.expected):
            self.divergence = Divergence(self.matched, self.expected[self.matched], None)


def compare(path: str | Path, *, links: Iterable[str] = ("pc",), scenario: str | None = None,
            timeout_s: float = 300.0) -> CompareResult:
    """Replay ``links`` of a virtual-clock recording into a fresh run of its scenario and
    compare every other link's frames with the recording."""
    path = Path(path)
    replayed = parse_links(links)
    meta = read_metadata(path)
    if meta.get("log_time", "sim") != "sim" or meta.get("clock", "virtual") != "virtual":
        raise CompareError(f"{path} was recorded on the wall clock: only virtual-clock runs can be "
                           "compared (their sim times are reproducible)")
    ref = scenario or meta.get("scenario")
    if not ref:
        raise CompareError(f"{path} does not say which scenario it ran (no 'scenario' in its metadata); "
                           "give one with --scenario")
    try:
        sc = resolve_scenario(str(ref), profile=meta.get("profile"), seed=meta.get("seed"))
    except ValueError as exc:  # ScenarioError is a ValueError
        raise CompareError(f"cannot rebuild the run of {path}: {exc}") from None
    frames = list(read_frames(path))
    end_ns = max((s.log_time_ns for s in iter_samples(path)), default=0) - sim_origin(meta)
    expected = [e for e in frames if e.link not in replayed]
    compared = tuple(link for link in LINKS if link not in replayed)
    cmp = _Comparator(expected, frozenset(compared), end_ns)
    pc_sources = tuple(dict.fromkeys(["pc"] + [e.src for e in frames if e.link == "pc"]))
    with VirtualRun(sc, attach=lambda bus: bus.subscribe_frames(cmp.on_frame), pcs=pc_sources) as run:
        replay = BusReplay(run.bus, [e for e in frames if e.link in replayed], replayed, pcs=run.pcs)
        replay.schedule()
        run.clock.run(until_ns=end_ns, until=lambda: cmp.divergence is not None, timeout_s=timeout_s)
    cmp.finish()
    return CompareResult(path, replayed, compared, len(replay), len(expected), cmp.matched, end_ns,
                         cmp.divergence, cmp.trailing)


def first_divergence(expected: Iterable[Envelope], got: Iterable[Envelope]) -> tuple[int, Divergence | None]:
    """(frames compared, the first that differs) between two runs' frames, in order: link,
    endpoints, channel, sim time and bytes."""
    a, b = list(expected), list(got)
    for i in range(max(len(a), len(b))):
        x = a[i] if i < len(a) else None
        y = b[i] if i < len(b) else None
        if x is None or y is None or _identity(x) != _identity(y):
            return max(len(a), len(b)), Divergence(i, x, y)
    return len(a), None


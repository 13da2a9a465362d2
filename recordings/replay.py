"""Visual replay of a recording with rerun: the lattice, the modules as hexagons moving over
sim time (120° rotations animated), their magnets, joints, LEDs and lit IR transceivers, every
frame as a text log per link, planner overlays, energy and frames-per-second plots.

Everything is gathered into columns first and sent with ``rr.send_columns`` (one call per
entity and archetype): an order of magnitude faster than one ``rr.log`` per row.
Timeline: ``sim_time`` (a duration, ns).

The live view (:mod:`recordings.live_rerun`) draws with the same :class:`ReplayBuilder`, a flush
at a time: :meth:`ReplayBuilder.render` takes a horizon, and each :class:`ModuleTrack` keeps
its drawing state from one call to the next.
"""

from __future__ import annotations

import heapq
import uuid
from collections import Counter, defaultdict, deque
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bus.codec import Kind, Link
from bus.envelope import Envelope
from bus.lattice import Cell
from bus.messages import Actuators, Energy, PlannerProgress, PlannerState, Pose, WorldEvent

from .player import Player
from .reader import Undecodable
from .lines import FrameLines
from .scene import (GOAL, JOINT_CLOSED, JOINT_INSET, JOINT_OPEN, LED_JOINT, LED_JOINT_INSET, LED_NEG,
                    LED_NEG_INSET, LED_POS, LED_POS_INSET, MAGNET_COLOURS, MAGNET_INSET, Move, Placement,
                    module_colour, rest)
from .schemas import RECORDER_ERROR_TOPIC

TIMELINE = "sim_time"
APP_ID = "hexbench"

# Colours (RGB) of what only the replay draws; a module's own are recordings.scene's (every viewer's).
GRID = (70, 70, 70)
MAGNET = MAGNET_COLOURS
IR_LIT = (255, 255, 150)
ELECTRON, VOID, POTENTIAL_VOID, PAIR = (255, 220, 0), (20, 20, 20), (255, 140, 0), (255, 255, 255)
_IR_COLOURS = [[IR_LIT] * n for n in range(8)]
_FRAME_ENTITY = {link.value: f"frames/{link.value}" for link in Link}
#: Stops of the value-function colour map (dark blue -> teal -> yellow), by value 0..1.
HEAT_STOPS = np.array([[40, 30, 110], [30, 120, 160], [60, 190, 120], [240, 230, 60]], dtype=float)


def view_xy(pts: Any) -> np.ndarray:
    """Lattice plane (y up) -> rerun's 2D view (y down)."""
    a = np.asarray(pts, dtype=np.float32).copy()
    if a.size == 0:
        return np.zeros((0, 2), dtype=np.float32)
    a[..., 1] *= -1
    return a


def cell_centre(c: Iterable[int]) -> tuple[float, float]:
    x, y = c
    return Cell(int(x), int(y)).centre()


def heat(values: list[float]) -> np.ndarray:
    """Colours of a value function, scaled over its own range."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return np.zeros((0, 3), dtype=np.uint8)
    span = v.max() - v.min()
    f = (v - v.min()) / span if span > 0 else np.zeros_like(v)
    pos = f * (len(HEAT_STOPS) - 1)
    i = np.minimum(pos.astype(int), len(HEAT_STOPS) - 2)
    w = (pos - i)[:, None]
    return (HEAT_STOPS[i] * (1 - w) + HEAT_STOPS[i + 1] * w).astype(np.uint8)


# --- columns -----------------------------------------------------------------------------------
@dataclass
class Columns:
    """Rows of one archetype on one entity, sent in one ``send_columns`` call.

    Every field of a row has the same number of instances (``n``); rows may be empty (clear)."""

    archetype: Any
    times: list[int] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    fields: dict[str, list[Any]] = field(default_factory=lambda: defaultdict(list))

    def add(self, t_ns: int, **values: Any) -> None:
        n = None
        for name, v in values.items():
            v = list(v)
            n = len(v) if n is None else n
            if len(v) != n:
                raise ValueError(f"{name}: {len(v)} instances, others have {n}")
            self.fields[name].extend(v)
        self.times.append(t_ns)
        self.lengths.append(n or 0)

    def add_row(self, t_ns: int, n: int, **values: list[Any]) -> None:
        """A row whose fields the caller guarantees to hold ``n`` instances each (hot paths)."""
        fields = self.fields
        for name, v in values.items():
            fields[name].extend(v)
        self.times.append(t_ns)
        self.lengths.append(n)

    def add_one(self, t_ns: int, **values: Any) -> None:
        """A row of exactly one instance per field (text lines, scalars): no checks needed."""
        fields = self.fields
        for name, v in values.items():
            fields[name].append(v)
        self.times.append(t_ns)
        self.lengths.append(1)

    def send(self, entity: str, rec: rr.RecordingStream) -> None:
        if not self.times:
            return
        cols = self.archetype.columns(**{k: _packed(v) for k, v in self.fields.items()}).partition(self.lengths)
        rec.send_columns(entity, indexes=[rr.TimeColumn(TIMELINE, duration=np.array(self.times, dtype="timedelta64[ns]"))],
                         columns=cols)


def _packed(values: list[Any]) -> Any:
    """Equal-shaped arrays stacked into one: rerun converts an ndarray in one go instead of
    one small array at a time (10x faster for strips and points)."""
    if values and isinstance(values[0], np.ndarray):
        shape = values[0].shape
        if all(isinstance(v, np.ndarray) and v.shape == shape for v in values):
            return np.stack(values)
    return values


class Scene:
    """All the columns of a replay, by entity and archetype."""

    def __init__(self) -> None:
        self._cols: dict[tuple[str, Any], Columns] = {}

    def columns(self, entity: str, archetype: Any) -> Columns:
        """The columns of one entity and archetype (created on first use)."""
        key = (entity, archetype)
        cols = self._cols.get(key)
        if cols is None:
            cols = self._cols[key] = Columns(archetype)
        return cols

    def add(self, entity: str, archetype: Any, t_ns: int, **values: Any) -> None:
        self.columns(entity, archetype).add(t_ns, **values)

    def text(self, entity: str, t_ns: int, text: str, level: str = "INFO") -> None:
        key = (entity, rr.TextLog)
        cols = self._cols.get(key)
        if cols is None:
            cols = self._cols[key] = Columns(rr.TextLog)
        cols.add_one(t_ns, text=text, level=level)

    def scalar(self, entity: str, t_ns: int, value: float) -> None:
        key = (entity, rr.Scalars)
        cols = self._cols.get(key)
        if cols is None:
            cols = self._cols[key] = Columns(rr.Scalars)
        cols.add_one(t_ns, scalars=value)

    def send(self, rec: rr.RecordingStream) -> None:
        for (entity, _), cols in self._cols.items():
            cols.send(entity, rec)

    def clear(self) -> None:
        """Forget the rows gathered so far (a live view sends them a flush at a time)."""
        self._cols.clear()

    @property
    def rows(self) -> int:
        return sum(len(c.times) for c in self._cols.values())


# --- one module's track ------------------------------------------------------------------------
class ModuleTrack:
    """One module's drawing: the events that change how it is drawn (poses, actuators, moves,
    IR bursts), added in any order and painted in time order by :meth:`paint`.

    The state it paints with (placement, actuators, the move in progress and its animation
    frames still to draw, lit transceivers) carries over from one :meth:`paint` to the next, so
    a replay (everything at once) and a live view (a flush at a time) draw the same rows.
    """

    def __init__(self, name: str, *, anim_step_ns: int = 20_000_000,
                 ir_cache: dict[tuple[Placement, tuple[int, ...]], list[np.ndarray]] | None = None) -> None:
        self.name = name
        self.anim_step_ns = anim_step_ns
        self.base = f"world/modules/{name}"
        self.colour = module_colour(name)
        self.real = False  # a real board (its body drawn from its twin's or its own bits) says so in its label
        self._queue: list[tuple[int, int, str, Any]] = []  # heap of (t, order added, what, value)
        self._added = 0
        self._ir_strips = {} if ir_cache is None else ir_cache
        self.placement: Placement | None = None
        self.act: Actuators | None = None
        self.move: Move | None = None
        self.pending: deque[int] = deque()  # animation frames of the move not drawn yet
        self.lit = [0] * 7  # bursts in flight per transceiver (0 centre, 1..6 sides)

    def add(self, t_ns: int, what: str, value: Any) -> None:
        # The order added breaks ties of equal times (and keeps values from being compared).
        heapq.heappush(self._queue, (t_ns, self._added, what, value))
        self._added += 1
        if what == "pose" and getattr(value, "kind", "") == "real":
            self.real = True

    @property
    def label(self) -> str:
        """The name drawn next to the outline."""
        return f"{self.name} real" if self.real else self.name

    def paint(self, scene: Scene, until_ns: int | None = None) -> None:
        """Draw the events before ``until_ns`` and the animation frames before it into
        ``scene``; None: everything, including the rest of a move still running at the end.

        Events added later with a time before an earlier ``until_ns`` are still drawn, at
        their own times, but with the state reached by then: callers hold ``until_ns`` back
        by the longest delay with which an event can arrive (an IR burst starts at its
        frame's first byte, known only when the frame is complete)."""
        q = self._queue
        ir_rows = scene.columns(f"{self.base}/ir", rr.LineStrips2D)
        while q and (until_ns is None or q[0][0] < until_ns):
            t, _, what, value = heapq.heappop(q)
            self._frames_before(scene, t)
            if what == "pose":
                self.move = None
                self.pending.clear()
                self.placement = rest(Cell(value.x, value.y), value.orientation)
                scene.add(self.base, rr.AnyValues, t, x=[value.x], y=[value.y], orientation=[value.orientation])
                self._draw(scene, t, self.placement)
            elif what == "actuators":
                self.act = value
                if self.placement is not None:
                    self._draw(scene, t, self.move.at(t) if self.move is not None else self.placement)
            elif what == "move" and self.placement is not None:
                self.move = Move.from_event(t, value, self.placement)
                if self.move is not None:
                    self.pending = deque(self.move.frame_times(self.anim_step_ns) + [self.move.end_ns])
                    self._draw(scene, t, self.move.at(t))
            elif what in ("ir-on", "ir-off") and self.placement is not None:
                if 0 <= value < 7:
                    self.lit[value] += 1 if what == "ir-on" else -1
                here = self.move.at(t) if self.move is not None else self.placement
                segs = self._ir(here, tuple(ch for ch in range(7) if self.lit[ch] > 0))
                ir_rows.add_row(t, len(segs), strips=segs, colors=_IR_COLOURS[len(segs)])
        self._frames_before(scene, until_ns)

    def _frames_before(self, scene: Scene, t_ns: int | None) -> None:
        """The move's animation frames before ``t_ns`` (None: all of them)."""
        pending = self.pending
        while pending and (t_ns is None or pending[0] < t_ns):
            ft = pending.popleft()
            if self.move is not None:
                self._draw(scene, ft, self.move.at(ft))

    def _ir(self, here: Placement, channels: tuple[int, ...]) -> list[np.ndarray]:
        """Lit IR segments of a placement (cached: a resting module lights the same ones often)."""
        key = (here, channels)
        segs = self._ir_strips.get(key)
        if segs is None:
            segs = [view_xy(here.ir_segment(ch)) for ch in channels]
            if here.pivot is None:  # rotating placements are seen once
                self._ir_strips[key] = segs
        return segs

    def _draw(self, s: Scene, t: int, p: Placement) -> None:
        """The module at placement ``p``: outline, magnets, joints, LEDs (with its actuators)."""
        base, act = self.base, self.act
        s.add(base, rr.LineStrips2D, t, strips=[view_xy(p.outline())], colors=[self.colour], labels=[self.label])
        magnets = act.magnets if act is not None else [0] * 6
        s.add(f"{base}/magnets", rr.LineStrips2D, t, strips=list(view_xy(p.side_segments(MAGNET_INSET))),
              colors=[MAGNET.get(m, MAGNET[2]) for m in magnets[:6]] + [MAGNET[0]] * (6 - len(magnets[:6])))
        opened = act.joints_open if act is not None else [False] * 6
        opened = list(opened[:6]) + [False] * (6 - len(opened[:6]))
        s.add(f"{base}/joints", rr.Points2D, t, positions=view_xy(p.joint_points(JOINT_INSET)),
              colors=[JOINT_OPEN if o else JOINT_CLOSED for o in opened],
              radii=[0.07 if o else 0.04 for o in opened])
        pts: list[np.ndarray] = []
        cols: list[tuple[int, int, int]] = []
        if act is not None:
            for flags, where, c in ((act.led_pos, p.side_points(LED_POS_INSET), LED_POS),
                                    (act.led_neg, p.side_points(LED_NEG_INSET), LED_NEG),
                                    (act.led_joint, p.joint_points(LED_JOINT_INSET), LED_JOINT)):
                for i, on in enumerate(flags[:6]):
                    if on:
                        pts.append(where[i])
                        cols.append(c)
        s.add(f"{base}/leds", rr.Points2D, t, positions=view_xy(np.array(pts)).reshape(-1, 2),
              colors=cols, radii=[0.035] * len(pts))


@lru_cache(maxsize=4096)
def _module_of(endpoint: str) -> str | None:
    """``m3.comm`` -> ``m3``; None for the PC or a bridge."""
    head = endpoint.split(".", 1)[0]
    return head if head.startswith("m") and head[1:].isdigit() else None


class ReplayBuilder:
    """Turns a :class:`Player`'s items into a :class:`Scene`."""

    def __init__(self, *, anim_step_ns: int = 20_000_000, fps_bin_ns: int = 100_000_000) -> None:
        self.anim_step_ns = anim_step_ns
        self.fps_bin_ns = fps_bin_ns
        self.scene = Scene()
        self.tracks: dict[str, ModuleTrack] = {}
        self.fps: dict[str, Counter[int]] = defaultdict(Counter)
        self.cells_seen: set[tuple[int, int]] = set()
        self.end_ns = 0
        self.frames = 0
        self._lines = FrameLines()
        self._ir_strips: dict[tuple[Placement, tuple[int, ...]], list[np.ndarray]] = {}
        self._fps_next: dict[str, int] = {}  # per link: the first bin not plotted yet

    def track(self, module: str) -> ModuleTrack:
        t = self.tracks.get(module)
        if t is None:
            t = self.tracks[module] = ModuleTrack(module, anim_step_ns=self.anim_step_ns, ir_cache=self._ir_strips)
        return t

    # -- gathering ----------------------------------------------------------------------------------
    def feed(self, items: Iterable[tuple[int, Any, Any]]) -> None:
        for t, sample, value in items:
            self.end_ns = max(self.end_ns, t)
            if isinstance(value, Envelope):
                self._frame(t, value)
            elif isinstance(value, Pose):
                self.cells_seen.add((value.x, value.y))
                self.track(value.module).add(t, "pose", value)
            elif isinstance(value, Actuators):
                self.track(value.module).add(t, "actuators", value)
            elif isinstance(value, WorldEvent):
                self._world_event(t, value)
            elif isinstance(value, Energy):
                self.scene.scalar("plots/energy/run_j", t, value.run_j)
                self.scene.scalar("plots/energy/move_j", t, value.move_j)
            elif isinstance(value, PlannerState):
                self._planner(t, value)
            elif isinstance(value, PlannerProgress):
                self.scene.text("events/planner", t, f"step {value.step} moves {value.moves} goal "
                                f"{value.goal_filled}/{value.goal_total} {value.message}".rstrip(),
                                "INFO" if value.ok else "ERROR")
            elif isinstance(value, Undecodable):
                self.scene.text("events/recorder", t, f"{sample.topic}: undecodable ({value.reason})", "ERROR")
            elif sample.topic == RECORDER_ERROR_TOPIC:
                self.scene.text("events/recorder", t, f"{value.get('key')}: {value.get('reason')} "
                                f"{value.get('detail', '')} [{value.get('payload_hex', '')[:64]}]", "ERROR")
            elif sample.topic.startswith("event/") and isinstance(value, dict):
                extra = " ".join(f"{k}={v}" for k, v in value.items() if k not in ("kind", "src", "sim_time_ns"))
                self.scene.text("events/bus", t, f"{value.get('src', sample.topic[6:])}: {value.get('kind')} {extra}".rstrip(), "WARN")

    def _frame(self, t: int, env: Envelope) -> None:
        self.frames += 1
        self.fps[env.link][t // self.fps_bin_ns] += 1
        level = "WARN" if env.kind == Kind.NOISE.value else "INFO"
        self.scene.text(_FRAME_ENTITY.get(env.link) or f"frames/{env.link}", t, self._lines.line(env), level)
        module = _module_of(env.src)
        if module is not None and env.channel is not None and env.link in (Link.SIDE.value, Link.CENTRE.value):
            start = t - max(0, env.sim_time_ns - env.first_byte_ns) if env.first_byte_ns is not None else t
            tr = self.track(module)
            tr.add(start, "ir-on", env.channel)
            tr.add(max(t, start + 1), "ir-off", env.channel)

    def _world_event(self, t: int, ev: WorldEvent) -> None:
        level = "ERROR" if ev.kind in ("fault", "collision") else "WARN" if ev.kind == "move-refused" else "INFO"
        extra = f" {ev.reason}" if ev.reason else ""
        self.scene.text("events/world", t, f"{ev.module or '-'}: {ev.kind}{extra}", level)
        if ev.module and ev.kind == "move-started":
            self.track(ev.module).add(t, "move", ev.data)

    def _planner(self, t: int, ps: PlannerState) -> None:
        s = self.scene
        for c in ps.occupied + ps.goal:
            self.cells_seen.add((c[0], c[1]))
        goal = [view_xy(np.vstack([v := np.array(Cell(*g).vertices()), v[:1]])) for g in ps.goal]
        s.add("planner/goal", rr.LineStrips2D, t, strips=goal, colors=[GOAL] * len(goal))
        for name, cells, colour, r in (("electrons", ps.electrons, ELECTRON, 0.16),
                                       ("voids", ps.voids, VOID, 0.16),
                                       ("potential_voids", ps.potential_voids, POTENTIAL_VOID, 0.12)):
            s.add(f"planner/{name}", rr.Points2D, t, positions=view_xy([cell_centre(c) for c in cells]).reshape(-1, 2),
                  colors=[colour] * len(cells), radii=[r] * len(cells))
        origins = view_xy([cell_centre(p[0]) for p in ps.pairs]).reshape(-1, 2)
        ends = view_xy([cell_centre(p[1]) for p in ps.pairs]).reshape(-1, 2)
        s.add("planner/pairs", rr.Arrows2D, t, origins=origins, vectors=ends - origins,
              colors=[PAIR] * len(ps.pairs))
        n = min(len(ps.value_cells), len(ps.values))
        s.add("planner/value", rr.Points2D, t,
              positions=view_xy([cell_centre(c) for c in ps.value_cells[:n]]).reshape(-1, 2),
              colors=heat(ps.values[:n]), radii=[0.5] * n)

    # -- rendering the modules --------------------------------------------------------------------------
    def render(self, until_ns: int | None = None) -> Scene:
        """Draw the module tracks and the frames-per-second series into :attr:`scene`.

        ``until_ns`` None: everything (a replay, or the end of a live run). Otherwise only
        what lies before it; the next call goes on from there (a live view, a flush at a time).
        """
        for tr in self.tracks.values():
            tr.paint(self.scene, until_ns)
        for link, bins in self.fps.items():
            lo = self._fps_next.get(link, min(bins))
            hi = max(bins) + 2  # one empty bin after the last: the line drops to 0
            if until_ns is not None:
                hi = min(hi, until_ns // self.fps_bin_ns)  # bins that are complete
            for b in range(lo, hi):
                self.scene.scalar(f"plots/fps/{link}", b * self.fps_bin_ns, bins.get(b, 0) * 1e9 / self.fps_bin_ns)
            self._fps_next[link] = max(lo, hi)
        return self.scene

    def grid(self, margin: int = 2) -> list[np.ndarray]:
        """Outlines of the lattice cells around everything seen."""
        if not self.cells_seen:
            return []
        xs = [c[0] for c in self.cells_seen]
        ys = [c[1] for c in self.cells_seen]
        out = []
        for x in range(min(xs) - margin, max(xs) + margin + 1):
            for y in range(min(ys) - margin, max(ys) + margin + 1):
                v = np.array(Cell(x, y).vertices())
                out.append(view_xy(np.vstack([v, v[:1]])))
        return out


# --- the viewer side -----------------------------------------------------------------------------
def blueprint() -> rrb.Blueprint:
    """The layout a replay opens on: the lattice left, plots and logs right."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial2DView(name="Lattice", origin="/", contents=["+ /world/**", "+ /planner/**"]),
            rrb.Vertical(
                rrb.TimeSeriesView(name="Energy (J)", origin="/plots/energy"),
                rrb.TimeSeriesView(name="Frames per second", origin="/plots/fps"),
                rrb.TextLogView(name="Frames", origin="/frames"),
                rrb.TextLogView(name="Events", origin="/events"),
                row_shares=[1, 1, 2, 1],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline=TIMELINE),
        collapse_panels=False,
    )


@dataclass
class ReplayStats:
    samples: int
    frames: int
    rows: int
    sim_ns: int
    wall_s: float
    damaged: list = field(default_factory=list)  # reader.Damage of chunks that were skipped

    @property
    def speed(self) -> float:
        """Sim seconds replayed per wall second."""
        return (self.sim_ns / 1e9) / self.wall_s if self.wall_s > 0 else float("inf")


def send_styles(rec: rr.RecordingStream) -> None:
    """Static styles: draw orders (value map and lattice below the modules), series names."""
    rec.log("planner/value", rr.Points2D.from_fields(draw_order=-10.0), static=True)
    rec.log("world/lattice", rr.LineStrips2D.from_fields(draw_order=-20.0), static=True)
    for name in ("run_j", "move_j"):
        rec.log(f"plots/energy/{name}", rr.SeriesLines(names=name), static=True)


def send_grid(rec: rr.RecordingStream, grid: list[np.ndarray]) -> None:
    """The lattice cells around everything seen (static: a later call replaces it)."""
    if grid:
        rec.log("world/lattice", rr.LineStrips2D(grid, colors=[GRID], radii=[0.01]), static=True)


def send_meta(rec: rr.RecordingStream, meta: dict[str, Any]) -> None:
    """The run's metadata as recording properties, and a recording name made of it."""
    if meta:
        rec.send_property("hexbench", rr.AnyValues(**{k: str(v) for k, v in sorted(meta.items())}))
        rec.send_recording_name(f"{meta.get('scenario', 'run')} ({meta.get('profile', '?')}, seed {meta.get('seed', '?')})")


def _send_static(rec: rr.RecordingStream, b: ReplayBuilder, meta: dict[str, Any]) -> None:
    send_grid(rec, b.grid())
    send_styles(rec)
    send_meta(rec, meta)


def rerun_binary() -> str:
    """The ``rerun`` CLI of the installed SDK (next to the Python interpreter)."""
    import shutil
    import sys
    here = Path(sys.executable).with_name("rerun")
    return str(here) if here.exists() else (shutil.which("rerun") or "rerun")


#: ``progress(phase, done, total)`` of a replay: "reading", "drawing" (samples), "sending" (rows).
ReplayProgress = Callable[[str, int, "int | None"], None]


def _counted(items: Iterable[Any], total: int, progress: ReplayProgress, every: int = 10_000) -> Iterator[Any]:
    for n, item in enumerate(items, 1):
        if n % every == 0:
            progress("drawing", n, total)
        yield item
    progress("drawing", total, total)


def replay(path: str | Path, *, rrd: str | Path | None = None, spawn: bool = False,
           recording_id: str | None = None, anim_step_ns: int = 20_000_000,
           progress: ReplayProgress | None = None) -> ReplayStats:
    """Replay a recording into an .rrd file and/or a spawned viewer (``progress`` is told
    how far it is)."""
    import time
    if rrd is None and not spawn:
        raise ValueError("replay needs an .rrd path or spawn=True")
    t0 = time.perf_counter()
    if progress is not None:
        progress("reading", 0, None)
    player = Player(path)
    builder = ReplayBuilder(anim_step_ns=anim_step_ns)
    items = player.items()
    builder.feed(items if progress is None else _counted(items, len(player), progress))
    scene = builder.render()
    if progress is not None:
        progress("sending", 0, None)
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id or str(uuid.uuid4()))
    bp = blueprint()
    if rrd is not None:
        rec.save(rrd, default_blueprint=bp)
    else:
        rec.spawn(default_blueprint=bp)
    _send_static(rec, builder, player.metadata)
    scene.send(rec)
    rec.flush()
    rec.disconnect()
    if spawn and rrd is not None:  # both: open the written file in a viewer
        import subprocess
        subprocess.Popen([rerun_binary(), str(rrd)], start_new_session=True)
    return ReplayStats(len(player), builder.frames, scene.rows, max(builder.end_ns, player.duration_ns),
                       time.perf_counter() - t0, player.damaged)

"""Visual replay of a recording with rerun: the lattice, the modules as hexagons moving over
sim time (120° rotations animated), their magnets, joints, LEDs and lit IR transceivers, every
frame as a text log per link, planner overlays, energy and frames-per-second plots.

Everything is gathered into columns first and sent with ``rr.send_columns`` (one call per
entity and archetype): an order of magnitude faster than one ``rr.log`` per row.
Timeline: ``sim_time`` (a duration, ns).
"""

from __future__ import annotations

import uuid
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from bus.codec import Frame, Kind, Link
from bus.envelope import Envelope
from bus.lattice import Cell
from bus.messages import Actuators, Energy, PlannerProgress, PlannerState, Pose, WorldEvent

from .player import Player
from .reader import Undecodable
from .scene import (JOINT_INSET, LED_JOINT_INSET, LED_NEG_INSET, LED_POS_INSET, MAGNET_INSET, Move,
                    Placement, rest)
from .schemas import RECORDER_ERROR_TOPIC

TIMELINE = "sim_time"
APP_ID = "hexbench"

# Colours (RGB).
GRID = (70, 70, 70)
MAGNET = {1: (235, 60, 60), -1: (60, 110, 240), 0: (95, 95, 95), 2: (255, 0, 255)}
JOINT_OPEN, JOINT_CLOSED = (255, 170, 0), (45, 45, 45)
LED_POS, LED_NEG, LED_JOINT = (255, 80, 80), (90, 140, 255), (255, 230, 60)
IR_LIT = (255, 255, 150)
PALETTE = [(120, 200, 255), (160, 230, 140), (250, 180, 120), (210, 160, 250), (250, 230, 120),
           (130, 230, 220), (250, 150, 190), (190, 190, 190)]
ELECTRON, VOID, POTENTIAL_VOID, PAIR, GOAL = (255, 220, 0), (20, 20, 20), (255, 140, 0), (255, 255, 255), (60, 220, 90)
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

    @property
    def rows(self) -> int:
        return sum(len(c.times) for c in self._cols.values())


# --- one module's track ------------------------------------------------------------------------
@dataclass
class ModuleTrack:
    """Everything that changes how one module is drawn, gathered in time order."""

    name: str
    events: list[tuple[int, int, str, Any]] = field(default_factory=list)  # (t, order, what, value)

    def add(self, t_ns: int, what: str, value: Any) -> None:
        self.events.append((t_ns, len(self.events), what, value))


def _describe(env: Envelope) -> str:
    try:
        return Frame(Link(env.link), Kind(env.kind), env.raw, env.view).describe()
    except (KeyError, ValueError, TypeError):  # a view we cannot print: show the bytes
        return f"{env.kind or '?'} {env.raw.hex()}"


def _frame_line(env: Envelope, cache: dict[tuple[str, str, str, str, bytes], str]) -> str:
    """The text-log line of a frame. A run repeats the same frames between the same
    endpoints over and over (probes, MSG1, ACKs), so lines are made once per distinct
    (link, src, dst, kind, bytes): the view is a function of the bytes."""
    key = (env.link, env.src, env.dst, env.kind, env.raw)
    line = cache.get(key)
    if line is None:
        line = cache[key] = f"{env.src} → {env.dst}  {_describe(env)}  [{env.raw.hex()}]"
    return line


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
        self._lines: dict[tuple[str, str, str, str, bytes], str] = {}
        self._ir_strips: dict[tuple[Placement, tuple[int, ...]], list[np.ndarray]] = {}

    def track(self, module: str) -> ModuleTrack:
        t = self.tracks.get(module)
        if t is None:
            t = self.tracks[module] = ModuleTrack(module)
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
        self.scene.text(_FRAME_ENTITY.get(env.link) or f"frames/{env.link}", t, _frame_line(env, self._lines), level)
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
    def render(self) -> Scene:
        """Draw every module track, the grid and the frames-per-second series."""
        for tr in self.tracks.values():
            self._render_track(tr)
        for link, bins in self.fps.items():
            lo, hi = min(bins), max(bins)
            for b in range(lo, hi + 2):  # one empty bin after the last: the line drops to 0
                self.scene.scalar(f"plots/fps/{link}", b * self.fps_bin_ns, bins.get(b, 0) * 1e9 / self.fps_bin_ns)
        return self.scene

    def _render_track(self, tr: ModuleTrack) -> None:
        events = sorted(tr.events)
        placement: Placement | None = None
        act: Actuators | None = None
        move: Move | None = None
        lit = [0] * 7  # bursts in flight per transceiver (0 centre, 1..6 sides)
        base = f"world/modules/{tr.name}"
        ir_rows = self.scene.columns(f"{base}/ir", rr.LineStrips2D)
        colour = PALETTE[(int(tr.name[1:]) - 1) % len(PALETTE)] if tr.name[1:].isdigit() else PALETTE[-1]
        # a real board (its body drawn from its twin's or its own bits) says so in its label
        real = any(what == "pose" and getattr(value, "kind", "") == "real" for _, _, what, value in events)
        label = f"{tr.name} real" if real else tr.name

        def draw(t: int, p: Placement) -> None:
            self._draw_module(base, label, colour, t, p, act)

        pending: list[int] = []
        for t, _, what, value in events:
            while pending and pending[0] < t:  # animation frames before this event
                ft = pending.pop(0)
                if move is not None:
                    draw(ft, move.at(ft))
            if what == "pose":
                move, pending = None, []
                placement = rest(Cell(value.x, value.y), value.orientation)
                self.scene.add(base, rr.AnyValues, t, x=[value.x], y=[value.y],
                               orientation=[value.orientation])
                draw(t, placement)
            elif what == "actuators":
                act = value
                if placement is not None:
                    draw(t, move.at(t) if move is not None else placement)
            elif what == "move" and placement is not None:
                move = Move.from_event(t, value, placement)
                if move is not None:
                    pending = move.frame_times(self.anim_step_ns) + [move.end_ns]
                    draw(t, move.at(t))
            elif what in ("ir-on", "ir-off") and placement is not None:
                if 0 <= value < 7:
                    lit[value] += 1 if what == "ir-on" else -1
                here = move.at(t) if move is not None else placement
                segs = self._ir(here, tuple(ch for ch in range(7) if lit[ch] > 0))
                ir_rows.add_row(t, len(segs), strips=segs, colors=_IR_COLOURS[len(segs)])
        for ft in pending:  # a move still running when the recording ends
            if move is not None:
                draw(ft, move.at(ft))

    def _ir(self, here: Placement, channels: tuple[int, ...]) -> list[np.ndarray]:
        """Lit IR segments of a placement (cached: a resting module lights the same ones often)."""
        key = (here, channels)
        segs = self._ir_strips.get(key)
        if segs is None:
            segs = [view_xy(here.ir_segment(ch)) for ch in channels]
            if here.pivot is None:  # rotating placements are seen once
                self._ir_strips[key] = segs
        return segs

    def _draw_module(self, base: str, name: str, colour: tuple[int, int, int], t: int,
                     p: Placement, act: Actuators | None) -> None:
        s = self.scene
        s.add(base, rr.LineStrips2D, t, strips=[view_xy(p.outline())], colors=[colour], labels=[name])
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


def _send_static(rec: rr.RecordingStream, b: ReplayBuilder, meta: dict[str, Any]) -> None:
    grid = b.grid()
    if grid:
        rec.log("world/lattice", rr.LineStrips2D(grid, colors=[GRID], radii=[0.01]), static=True)
    rec.log("planner/value", rr.Points2D.from_fields(draw_order=-10.0), static=True)
    rec.log("world/lattice", rr.LineStrips2D.from_fields(draw_order=-20.0), static=True)
    for name in ("run_j", "move_j"):
        rec.log(f"plots/energy/{name}", rr.SeriesLines(names=name), static=True)
    if meta:
        rec.send_property("hexbench", rr.AnyValues(**{k: str(v) for k, v in sorted(meta.items())}))
        rec.send_recording_name(f"{meta.get('scenario', 'run')} ({meta.get('profile', '?')}, seed {meta.get('seed', '?')})")


def rerun_binary() -> str:
    """The ``rerun`` CLI of the installed SDK (next to the Python interpreter)."""
    import shutil
    import sys
    here = Path(sys.executable).with_name("rerun")
    return str(here) if here.exists() else (shutil.which("rerun") or "rerun")


def replay(path: str | Path, *, rrd: str | Path | None = None, spawn: bool = False,
           recording_id: str | None = None, anim_step_ns: int = 20_000_000) -> ReplayStats:
    """Replay a recording into an .rrd file and/or a spawned viewer."""
    import time
    if rrd is None and not spawn:
        raise ValueError("replay needs an .rrd path or spawn=True")
    t0 = time.perf_counter()
    player = Player(path)
    builder = ReplayBuilder(anim_step_ns=anim_step_ns)
    builder.feed(player.items())
    scene = builder.render()
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

"""Geometry of the replay, free of any viewer: where a module's outline, magnets, joints,
LEDs and IR transceivers are for a pose, and where they are during a 120° rotation.

Coordinates are the lattice's Cartesian plane (:meth:`bus.lattice.Cell.centre`, y up).
A module's body side ``s`` is global side ``s + orientation`` (:func:`bus.lattice.body_to_global`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Mapping

import numpy as np

from bus.lattice import Cell, Side, body_to_global, joint_body_to_global

#: Insets towards the centre, so the parts of a module do not sit on its neighbour's.
MAGNET_INSET = 0.86
JOINT_INSET = 0.9
LED_POS_INSET = 0.70
LED_NEG_INSET = 0.58
LED_JOINT_INSET = 0.76
IR_INSET = 0.97
IR_HALF = 0.18  # half length of a lit IR segment, as a fraction of the side


@dataclass(frozen=True)
class Placement:
    """Where a module is drawn: its resting pose, possibly rotated about a pivot."""

    cell: Cell
    orientation: int
    pivot: tuple[float, float] | None = None
    angle_deg: float = 0.0  # positive = counter-clockwise

    def apply(self, pts: np.ndarray) -> np.ndarray:
        """Points of the resting pose moved by this placement's rotation."""
        if self.pivot is None or self.angle_deg == 0.0:
            return pts
        a = math.radians(self.angle_deg)
        rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        piv = np.asarray(self.pivot)
        return (pts - piv) @ rot.T + piv

    # -- the parts (all in global coordinates) ---------------------------------------------------
    def centre(self) -> np.ndarray:
        return self.apply(np.array([self.cell.centre()]))[0]

    def outline(self) -> np.ndarray:
        """Closed strip of the six vertices (7 points)."""
        return self.apply(_rest_outline(self.cell))

    def side_segments(self, inset: float) -> np.ndarray:
        """Body sides 1..6 as segments (6, 2, 2), pulled towards the centre by ``inset``."""
        return self.apply(_rest_sides(self.cell, self.orientation, inset).reshape(-1, 2)).reshape(6, 2, 2)

    def side_points(self, inset: float) -> np.ndarray:
        """Midpoints of body sides 1..6 (6, 2)."""
        return self.side_segments(inset).mean(axis=1)

    def joint_points(self, inset: float) -> np.ndarray:
        """Body joints 1..6 (6, 2)."""
        return self.apply(_rest_joints(self.cell, self.orientation, inset))

    def ir_segment(self, channel: int) -> np.ndarray:
        """The lit part of IR transceiver ``channel`` (1..6 body side; 0 centre: a tiny cross)."""
        if channel == 0:
            c = self.centre()
            return np.array([c - (0.08, 0.0), c + (0.08, 0.0)])
        a, b = self.side_segments(IR_INSET)[Side.of(channel) - 1]
        mid = (a + b) / 2
        return np.array([mid - (b - a) * IR_HALF, mid + (b - a) * IR_HALF])


# The resting geometry of a pose never changes: computed once per (cell, orientation, inset).
def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _towards(cell: Cell, pts: np.ndarray, inset: float) -> np.ndarray:
    c = np.array(cell.centre())
    return c + (pts - c) * inset


@lru_cache(maxsize=4096)
def _rest_outline(cell: Cell) -> np.ndarray:
    v = np.array(cell.vertices())
    return _frozen(np.vstack([v, v[:1]]))


@lru_cache(maxsize=16384)
def _rest_sides(cell: Cell, orientation: int, inset: float) -> np.ndarray:
    segs = []
    for s in range(1, 7):
        a, b = body_to_global(s, orientation).joints
        segs.append([cell.vertex(a), cell.vertex(b)])
    return _frozen(_towards(cell, np.array(segs).reshape(-1, 2), inset).reshape(6, 2, 2))


@lru_cache(maxsize=16384)
def _rest_joints(cell: Cell, orientation: int, inset: float) -> np.ndarray:
    pts = np.array([cell.vertex(joint_body_to_global(j, orientation)) for j in range(1, 7)])
    return _frozen(_towards(cell, pts, inset))


def rest(cell: Cell, orientation: int) -> Placement:
    return Placement(cell, orientation % 6)


@dataclass(frozen=True)
class Move:
    """A 120° rotation from ``move-started`` data (spec §1; WorldEvent docstring)."""

    t0_ns: int
    duration_ns: int
    start: Placement
    pivot: tuple[float, float]
    sign: int  # +1 CCW, -1 CW

    @classmethod
    def from_event(cls, t0_ns: int, data: Mapping[str, Any], fallback: Placement) -> "Move | None":
        """None when the event lacks what the animation needs (the replay then just snaps)."""
        try:
            pivot = (float(data["pivot"][0]), float(data["pivot"][1]))
            sign = 1 if str(data["direction"]).upper() == "CCW" else -1
            duration = int(data.get("duration_ns") or 220_000_000)
        except (KeyError, TypeError, ValueError, IndexError):
            return None
        start = fallback
        if "from" in data:
            try:
                start = rest(Cell(int(data["from"][0]), int(data["from"][1])),
                             int(data.get("orientation_before", fallback.orientation)))
            except (TypeError, ValueError, IndexError):
                pass
        return cls(t0_ns, max(duration, 1), start, pivot, sign)

    @property
    def end_ns(self) -> int:
        return self.t0_ns + self.duration_ns

    def at(self, t_ns: int) -> Placement:
        f = min(max((t_ns - self.t0_ns) / self.duration_ns, 0.0), 1.0)
        return Placement(self.start.cell, self.start.orientation, self.pivot, self.sign * 120.0 * f)

    def frame_times(self, step_ns: int) -> list[int]:
        """Times of the in-between frames (start and end excluded)."""
        return list(range(self.t0_ns + step_ns, self.end_ns, step_ns))


# --- colours (RGB 0..255), one set for every viewer ------------------------------------------------
MAGNET_COLOURS = {1: (235, 60, 60), -1: (60, 110, 240), 0: (95, 95, 95), 2: (255, 0, 255)}  # +, -, off, both
JOINT_OPEN, JOINT_CLOSED = (255, 170, 0), (45, 45, 45)
LED_POS, LED_NEG, LED_JOINT = (255, 80, 80), (90, 140, 255), (255, 230, 60)
GOAL = (60, 220, 90)
MOVING = (255, 220, 0)
FIXED = (150, 150, 150)
PALETTE = [(120, 200, 255), (160, 230, 140), (250, 180, 120), (210, 160, 250), (250, 230, 120),
           (130, 230, 220), (250, 150, 190), (190, 190, 190)]


def module_colour(name: str) -> tuple[int, int, int]:
    """A module's own colour (``m3`` -> the third of the palette), the same in every viewer."""
    return PALETTE[(int(name[1:]) - 1) % len(PALETTE)] if name[1:].isdigit() else PALETTE[-1]

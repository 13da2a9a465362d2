"""The hexagonal lattice (thesis §4.3.1, Fig. 4-8, Table 4-1, Table 4-3; Matlab
``HexNe``, ``Hex``, ``HexNeM``, ``HexActuate``).

Cells have integer coordinates (x, y). Sides are numbered 1..6 clockwise from the
upper-left edge (side 2 is the top edge); joint (vertex) k lies between sides
k-1 and k, so side k runs from joint k to joint k+1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Iterable, Sequence

SIN60 = math.sin(math.radians(60))
TAN30 = math.tan(math.radians(30))
#: Half height of the unit hexagon (centre to edge) in the thesis's plotting units.
_B = 1 / (3 * TAN30)
#: Circumradius (centre to vertex).
CIRCUMRADIUS = 2 / 3


class Side(IntEnum):
    """A hexagon side 1..6."""

    S1 = 1
    S2 = 2
    S3 = 3
    S4 = 4
    S5 = 5
    S6 = 6

    @classmethod
    def of(cls, k: int) -> "Side":
        """Fold any integer into 1..6 the way the firmware does."""
        return _SIDES[(k - 1) % 6]  # a tuple, not cls(...): the enum call is slow on hot paths

    @property
    def facing(self) -> "Side":
        """The neighbour's side that touches this one (Table 4-1)."""
        return Side.of(self + 3)

    @property
    def joints(self) -> tuple["Joint", "Joint"]:
        """The two vertices this side runs between: joint k and joint k+1."""
        return Joint.of(self), Joint.of(self + 1)


class Joint(IntEnum):
    """A hexagon vertex 1..6 (a solenoid on the module)."""

    J1 = 1
    J2 = 2
    J3 = 3
    J4 = 4
    J5 = 5
    J6 = 6

    @classmethod
    def of(cls, k: int) -> "Joint":
        return _JOINTS[(k - 1) % 6]

    @property
    def sides(self) -> tuple[Side, Side]:
        """The two sides that meet at this vertex: side k-1 and side k."""
        return Side.of(self - 1), Side.of(self)


_SIDES = tuple(Side)
_JOINTS = tuple(Joint)

#: Table 4-1: offset of the neighbour across each side, in the global frame.
NEIGHBOUR_OFFSET: dict[Side, tuple[int, int]] = {
    Side.S1: (-1, 1),
    Side.S2: (0, 1),
    Side.S3: (1, 0),
    Side.S4: (1, -1),
    Side.S5: (0, -1),
    Side.S6: (-1, 0),
}

_OFFSETS = tuple(NEIGHBOUR_OFFSET[s] for s in Side)


@dataclass(frozen=True, order=True)
class Cell:
    """A lattice cell in global hex coordinates."""

    x: int
    y: int

    def neighbour(self, side: int) -> "Cell":
        dx, dy = _OFFSETS[(side - 1) % 6]
        return Cell(self.x + dx, self.y + dy)

    def neighbours(self) -> list["Cell"]:
        return [self.neighbour(s) for s in Side]

    def side_towards(self, other: "Cell") -> Side | None:
        """The side of this cell that touches ``other``, or None if not adjacent."""
        d = (other.x - self.x, other.y - self.y)
        for s, off in NEIGHBOUR_OFFSET.items():
            if off == d:
                return s
        return None

    def distance(self, other: "Cell") -> int:
        """Hex distance (number of moves on an empty lattice)."""
        dx, dy = other.x - self.x, other.y - self.y
        return (abs(dx) + abs(dy) + abs(dx + dy)) // 2

    def centre(self) -> tuple[float, float]:
        """Cartesian centre (Matlab ``Hex``): px = x, py = y/sin60 + x*tan30."""
        return float(self.x), self.y / SIN60 + self.x * TAN30

    def vertex(self, joint: int) -> tuple[float, float]:
        """Cartesian position of a vertex (flat-top hexagon, circumradius 2/3)."""
        px, py = self.centre()
        dx, dy = _VERTEX_OFFSET[Joint.of(joint)]
        return px + dx, py + dy

    def vertices(self) -> list[tuple[float, float]]:
        return [self.vertex(j) for j in Joint]

    def __iter__(self):  # allows ``x, y = cell``
        yield self.x
        yield self.y

    def __str__(self) -> str:
        return f"({self.x},{self.y})"


_VERTEX_OFFSET: dict[Joint, tuple[float, float]] = {
    Joint.J1: (-2 / 3, 0.0),
    Joint.J2: (-1 / 3, _B),
    Joint.J3: (1 / 3, _B),
    Joint.J4: (2 / 3, 0.0),
    Joint.J5: (1 / 3, -_B),
    Joint.J6: (-1 / 3, -_B),
}


def rings(start: Cell, cells: Iterable[Cell]) -> dict[Cell, int]:
    """Cell -> hops from ``start`` through neighbouring ``cells`` (breadth first); cells not
    connected to ``start`` are absent. v2 localization reaches ring k in step k."""
    occupied = set(cells)
    dist = {start: 0} if start in occupied else {}
    frontier = list(dist)
    while frontier:
        nxt = []
        for c in frontier:
            for n in c.neighbours():
                if n in occupied and n not in dist:
                    dist[n] = dist[c] + 1
                    nxt.append(n)
        frontier = nxt
    return dist


def rotate_offset(offset: tuple[int, int], steps: int) -> tuple[int, int]:
    """Turn a cell offset by ``steps`` sides clockwise: the offset of side s becomes the
    offset of side s + steps (a frame whose side 1 is global side 1 + steps)."""
    x, y = offset
    for _ in range(steps % 6):
        x, y = x + y, -x
    return x, y


def offset_in_frame(cell: "Cell", reference: "Cell", orientation: int) -> tuple[int, int]:
    """The offset of ``cell`` from a module at ``reference`` whose orientation is
    ``orientation``, in that module's frame: what the protocol carries once that module is the
    reference (``Ref``: (0, 0), Yref 0). The inverse of turning a report into the global frame."""
    return rotate_offset((cell.x - reference.x, cell.y - reference.y), -orientation)


# --- body frame <-> global frame --------------------------------------------------
def body_to_global(side: int, yref: int) -> Side:
    """Global side of body side ``side`` for a module whose ``Yref`` is ``yref``.

    ``Yref`` counts the 60-degree steps between body and global frame; the
    localization rule ``Yref = S - j`` (global minus body side) defines its sign.
    """
    return Side.of(side + yref)


def global_to_body(side: int, yref: int) -> Side:
    return Side.of(side - yref)


def joint_body_to_global(joint: int, yref: int) -> Joint:
    return Joint.of(joint + yref)


def joint_global_to_body(joint: int, yref: int) -> Joint:
    return Joint.of(joint - yref)


# --- thesis matrices ---------------------------------------------------------------
def matrix_to_cells(matrix: Sequence[Sequence[int]] | Sequence[str]) -> list[Cell]:
    """Cells of a thesis 0/1 matrix: row i, column j of an R-row matrix (1-based) is
    the cell x = j-1, y = R-i (the top row is the highest y).

    Rows may be sequences of ints or strings like ``"1 0 1"``.
    """
    rows = [list(map(int, r.split())) if isinstance(r, str) else list(r) for r in matrix]
    n_rows = len(rows)
    cells: list[Cell] = []
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            if v not in (0, 1):
                raise ValueError(f"matrix row {i + 1} column {j + 1}: {v!r} is not 0 or 1")
            if v:
                cells.append(Cell(j, n_rows - 1 - i))
    return sorted(cells, key=lambda c: (c.y, c.x))


def cells_to_matrix(cells: Iterable[Cell], n_rows: int | None = None,
                    n_cols: int | None = None) -> list[list[int]]:
    """Inverse of :func:`matrix_to_cells` for cells with x >= 0 and y >= 0."""
    cells = list(cells)
    if any(c.x < 0 or c.y < 0 for c in cells):
        raise ValueError("cells with negative coordinates have no thesis matrix position")
    n_rows = n_rows if n_rows is not None else max((c.y for c in cells), default=-1) + 1
    n_cols = n_cols if n_cols is not None else max((c.x for c in cells), default=-1) + 1
    m = [[0] * n_cols for _ in range(n_rows)]
    for c in cells:
        m[n_rows - 1 - c.y][c.x] = 1
    return m


def matrix_offset_to_cell(origin: Cell, di: int, dj: int) -> Cell:
    """A (row, column) offset in a thesis matrix, applied to a cell (rows grow downwards)."""
    return Cell(origin.x + dj, origin.y - di)


# --- Table 4-3: which move, which actuators ------------------------------------------
class Direction(str, Enum):
    CW = "CW"
    CCW = "CCW"


#: Neighbours of a mobile module as in Fig. 4-30, in thesis-matrix offsets (row, column)
#: from the mobile cell (``HexActuate``). A..F are the sides 1..6; G..L the second ring
#: beyond joints 2, 3, 4, 5, 6, 1.
LETTER_OFFSET: dict[str, tuple[int, int]] = {
    "A": (-1, -1), "B": (-1, 0), "C": (0, 1), "D": (1, 1), "E": (1, 0), "F": (0, -1),
    "G": (-2, -1), "H": (-1, 1), "I": (1, 2), "J": (2, 1), "K": (1, -1), "L": (-1, -2),
}


@dataclass(frozen=True)
class MoveRule:
    """One row of Table 4-3."""

    joint: Joint
    direction: Direction
    substrate: str
    empty: tuple[str, str, str]
    goal: str

    def cells(self, mobile: Cell) -> tuple[Cell, tuple[Cell, ...], Cell]:
        """(substrate cell, cells that must be empty, goal cell) for a mobile at ``mobile``."""
        def at(letter: str) -> Cell:
            return matrix_offset_to_cell(mobile, *LETTER_OFFSET[letter])
        return at(self.substrate), tuple(at(e) for e in self.empty), at(self.goal)


def _rule(j: int, d: str, sub: str, empty: str, goal: str) -> MoveRule:
    return MoveRule(Joint(j), Direction(d), sub, tuple(empty.split(",")), goal)  # type: ignore[arg-type]


#: Table 4-3, row by row.
MOVE_RULES: tuple[MoveRule, ...] = (
    _rule(1, "CW", "A", "D,E,K", "F"),
    _rule(2, "CW", "B", "E,F,L", "A"),
    _rule(3, "CW", "C", "F,A,G", "B"),
    _rule(4, "CW", "D", "A,B,H", "C"),
    _rule(5, "CW", "E", "B,C,I", "D"),
    _rule(6, "CW", "F", "C,D,J", "E"),
    _rule(1, "CCW", "F", "C,B,G", "A"),
    _rule(2, "CCW", "A", "D,C,H", "B"),
    _rule(3, "CCW", "B", "E,D,I", "C"),
    _rule(4, "CCW", "C", "F,E,J", "D"),
    _rule(5, "CCW", "D", "A,F,K", "E"),
    _rule(6, "CCW", "E", "B,A,L", "F"),
)


def move_rule(joint: int, direction: Direction | str) -> MoveRule:
    d = Direction(direction)
    for r in MOVE_RULES:
        if r.joint == Joint.of(joint) and r.direction == d:
            return r
    raise KeyError((joint, direction))  # unreachable: the table is complete


def rule_for_step(mobile: Cell, goal: Cell, substrate: Cell | None = None) -> list[MoveRule]:
    """Rows of Table 4-3 that move a module from ``mobile`` to the adjacent ``goal``
    (optionally about a given ``substrate``)."""
    out = []
    for r in MOVE_RULES:
        sub, _, g = r.cells(mobile)
        if g == goal and (substrate is None or sub == substrate):
            out.append(r)
    return out


def rotate_about_vertex(point: tuple[float, float], pivot: tuple[float, float],
                        degrees: float) -> tuple[float, float]:
    """Rotate a Cartesian point about a pivot; positive degrees are counter-clockwise."""
    a = math.radians(degrees)
    x, y = point[0] - pivot[0], point[1] - pivot[1]
    return (pivot[0] + x * math.cos(a) - y * math.sin(a),
            pivot[1] + x * math.sin(a) + y * math.cos(a))

"""The paper's compass on the project's lattice (one geometry: :mod:`bus.lattice`).

Walter, Tsai and Amato draw columns as north-south chains, the intersection with I in the
westernmost column G_1 and the rest of G to the east. On :mod:`bus.lattice`'s flat-topped
cells a column is a constant ``x`` and the six neighbours are the six compass points below
(side 1 is north-west, side 2 north, clockwise). A goal is looked at in one of six
*orientations*: orientation ``k`` turns every cell ``k`` sides clockwise
(:func:`bus.lattice.rotate_offset`) before it is read with this compass.
"""

from __future__ import annotations

from enum import Enum
from typing import Iterable

from bus.lattice import NEIGHBOUR_OFFSET, Cell, Side, rotate_offset


class Heading(str, Enum):
    """A step between adjacent cells, on the paper's compass."""

    NW = "NW"
    N = "N"
    NE = "NE"
    SE = "SE"
    S = "S"
    SW = "SW"

    @property
    def side(self) -> Side:
        return _SIDE[self]

    @property
    def vertical(self) -> bool:
        return self in (Heading.N, Heading.S)

    @property
    def westward(self) -> bool:
        return self in (Heading.NW, Heading.SW)

    def offset(self) -> tuple[int, int]:
        return NEIGHBOUR_OFFSET[self.side]

    def of(self, cell: Cell) -> Cell:
        """The neighbour of ``cell`` in this heading."""
        return cell.neighbour(self.side)


_SIDE = {h: Side(i + 1) for i, h in enumerate(Heading)}
_BY_OFFSET = {h.offset(): h for h in Heading}


def heading(a: Cell, b: Cell) -> Heading | None:
    """The heading of the step ``a -> b``, None if the cells are not adjacent."""
    return _BY_OFFSET.get((b.x - a.x, b.y - a.y))


def turn(cell: Cell, k: int) -> Cell:
    """``cell`` seen in orientation ``k`` (turned ``k`` sides clockwise about the origin)."""
    return Cell(*rotate_offset((cell.x, cell.y), k))


def unturn(cell: Cell, k: int) -> Cell:
    """Back from orientation ``k`` to the lattice."""
    return Cell(*rotate_offset((cell.x, cell.y), -k))


def turn_all(cells: Iterable[Cell], k: int) -> list[Cell]:
    return [turn(c, k) for c in cells]


def columns(cells: Iterable[Cell]) -> dict[int, list[Cell]]:
    """The columns of ``cells`` (west to east), each listed north to south."""
    out: dict[int, list[Cell]] = {}
    for c in cells:
        out.setdefault(c.x, []).append(c)
    return {x: sorted(out[x], key=lambda c: -c.y) for x in sorted(out)}


def contiguous_columns(cells: Iterable[Cell]) -> tuple[int, int] | None:
    """None when every column of ``cells`` is one unbroken north-south chain and the
    columns run without a gap; else ``(x, y)`` of the first cell below a gap (a missing
    column is reported at its x with y = None-like 0)."""
    cols = columns(cells)
    xs = list(cols)
    for a, b in zip(xs, xs[1:]):
        if b != a + 1:
            return (a + 1, 0)
    for x, col in cols.items():
        for upper, lower in zip(col, col[1:]):
            if upper.y - lower.y != 1:
                return (x, lower.y)
    return None

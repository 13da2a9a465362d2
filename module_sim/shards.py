"""Shards of a fleet: which modules each process of a fleet spread over processes runs.

IR side light crosses a shard's border over zenoh (a :mod:`bus.lockstep` window late), so a
partition keeps neighbours together: the fewest neighbour pairs cut, parts of equal size
(the processes get equal work). Strips across the lattice's longer extent give a balanced
start; Kernighan-Lin bisection (networkx, seeded: the same scenario gives the same parts)
then trades modules across each border while that cuts fewer pairs. More than two parts:
recursive bisection, sizes in proportion.
"""

from __future__ import annotations

from typing import Sequence

import networkx as nx

from bus.lattice import Cell
from bus.timing import byte_time_ns


def neighbour_graph(cells: Sequence[Cell]) -> nx.Graph:
    """Cells (by index) joined where two share a side."""
    index = {c: i for i, c in enumerate(cells)}
    g = nx.Graph()
    g.add_nodes_from(range(len(cells)))
    for i, c in enumerate(cells):
        for n in c.neighbours():
            j = index.get(n)
            if j is not None and j > i:
                g.add_edge(i, j)
    return g


def partition(cells: Sequence[Cell], parts: int, *, seed: int = 0) -> list[int]:
    """The part (0..parts-1) of each cell: as equal in size as can be, few neighbours apart."""
    if parts < 1:
        raise ValueError(f"{parts} parts: need at least 1")
    if parts > len(cells):
        raise ValueError(f"{parts} parts for {len(cells)} modules: at most one part per module")
    g = neighbour_graph(cells)
    out = [0] * len(cells)

    def split(nodes: list[int], first: int, count: int) -> None:
        if count == 1:
            for i in nodes:
                out[i] = first
            return
        left_parts = count // 2
        # strips across the longer extent: a balanced, compact start
        xs = [cells[i].centre() for i in nodes]
        spread_x = max(p[0] for p in xs) - min(p[0] for p in xs)
        spread_y = max(p[1] for p in xs) - min(p[1] for p in xs)
        axis = 0 if spread_x >= spread_y else 1
        order = sorted(nodes, key=lambda i: (cells[i].centre()[axis], cells[i].centre()[1 - axis], i))
        cut = round(len(order) * left_parts / count)
        left, right = set(order[:cut]), set(order[cut:])
        if len(left) == len(right):  # Kernighan-Lin swaps pairs: it keeps the sizes only when equal
            left, right = nx.community.kernighan_lin_bisection(g.subgraph(nodes), (left, right),
                                                               seed=seed)
        split(sorted(left), first, left_parts)
        split(sorted(right), first + left_parts, count - left_parts)

    split(list(range(len(cells))), 0, parts)
    return out


def cut_pairs(cells: Sequence[Cell], part: Sequence[int]) -> int:
    """How many neighbour pairs the partition puts in different parts."""
    return sum(1 for i, j in neighbour_graph(cells).edges if part[i] != part[j])


def window_ns(ir_baud: int) -> int:
    """The lockstep window for a fleet whose shards exchange IR light at ``ir_baud``: half a
    byte time, down to the microsecond (16.666 ms at 300 baud, where a byte takes 33.3 ms).
    The planner's process, where the PC's receiver decodes what every shard's light made of
    each other, runs a window behind the shards (:data:`LAGS`): its light reaches them two
    windows late at most, still before its first byte ends."""
    return max(1, byte_time_ns(ir_baud) // 2 // 1000) * 1000


def parse_shard(text: str) -> tuple[int, int]:
    """``K/N`` (0 <= K < N): part K of N."""
    try:
        k, n = (int(v) for v in text.split("/"))
        if not 0 <= k < n:
            raise ValueError
    except ValueError:
        raise ValueError(f"--shard {text!r}: expected K/N with 0 <= K < N, e.g. 0/2") from None
    return k, n


def participants(n: int) -> list[str]:
    """The lockstep participants of a fleet in ``n`` shards: the planner's process, then each
    shard."""
    return [PLANNER] + [shard_name(k) for k in range(n)]


def shard_name(k: int) -> str:
    return f"s{k}"


PLANNER = "pc"
#: Windows each participant runs behind (bus.lockstep): the planner's process decodes light from
#: every shard at the PC's receiver, where bursts collide, so it runs one window behind and each
#: byte's value is final before its stop bit. A module's receiver hears one transmitter (its
#: facing neighbour, or the PC): nothing collides there.
LAGS = {PLANNER: 1}

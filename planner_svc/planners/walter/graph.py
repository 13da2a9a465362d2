"""Section 4 of Walter, Tsai & Amato: admissible paths, the directed graph H, TraverseGraph.

Everything here works on cells already turned into the paper's frame (:mod:`.frame`):
columns are constant ``x``, G_1 is the westernmost column, north is ``+y``.

* :func:`path_violation` -- Definition 2 (and 1: segments), one line naming the condition
  and the cell, or None.
* :func:`build_h` -- the directed graph H of a goal (a ``networkx.DiGraph``), with the
  edges it refused and why.
* :func:`traverse_graph` -- Figure 7: every root-to-leaf path of H from one root, each with
  its cost from the vertex weights 0 / 1 / 10.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Sequence

import networkx as nx

from bus.lattice import Cell

from .frame import Heading, columns, heading

#: Vertex weights (section 4, "Traversing and weighting H").
WEIGHT_VERTICAL, WEIGHT_TURN, WEIGHT_STRAIGHT = 10, 1, 0
#: The order TraverseGraph picks a vertex's children in (Figure 8 picks the northern first).
CHILD_ORDER = (Heading.N, Heading.NE, Heading.SE, Heading.S)


def corner_cells(path: Sequence[Cell], i: int, north: bool) -> tuple[Cell, Cell, Cell]:
    """X_i, Y_i, Z_i of Figure 4 for a vertical segment ending with ``path[i]``.

    Figure 4 is not in our copy of the paper; our reading: the cells that must stay empty
    are the concave corner on the east of the segment's end (where the path turns east)
    and the two cells beyond it, so that movers two cells apart can turn the corner.
    North segment: X = SE of c_i, Y = S of X (SE of c_(i-1)), Z = SE of X. South: mirrored.
    """
    c = path[i]
    if north:
        x = Heading.SE.of(c)
        return x, Heading.S.of(x), Heading.SE.of(x)
    x = Heading.NE.of(c)
    return x, Heading.N.of(x), Heading.NE.of(x)


def path_violation(path: Sequence[Cell], goal: frozenset[Cell] | set[Cell]) -> str | None:
    """Why ``path`` is not admissible (Definition 2), or None.

    Segments (Definition 1) are runs of at least two cells each north (or south) of the
    previous; every cell where a north segment ends is checked, so a long north run is
    checked at each of its cells.
    """
    steps = [heading(a, b) for a, b in zip(path, path[1:])]
    for i, h in enumerate(steps):
        if h is None:
            return f"Definition 2.1: {path[i + 1]} is not adjacent to {path[i]}"
        if h.westward:
            return f"Definition 2.1: {path[i]} -> {path[i + 1]} goes {h.value} (west)"
    if len(set(path)) != len(path):
        return "Definition 2: the path visits a cell twice"
    for i in range(1, len(path)):
        h = steps[i - 1]
        if not h.vertical:
            continue
        north = h is Heading.N
        rule = "2.2" if north else "2.3"
        name = "north" if north else "south"
        for cell in corner_cells(path, i, north):
            if cell in goal:
                return (f"Definition {rule}(a): {name} segment ending at {path[i]}: {cell} "
                        "is a goal cell (Figure 4: X, Y, Z must not be)")
        ahead = steps[i:i + 3][1:]  # steps c_(i+1)->c_(i+2), c_(i+2)->c_(i+3)
        if any(a is (Heading.S if north else Heading.N) for a in ahead):
            return (f"Definition {rule}(b): {name} segment ending at {path[i]} is followed "
                    f"within three cells by a {'south' if north else 'north'} segment")
    return None


def vertex_weights(path: Sequence[Cell]) -> list[int]:
    """The weight of each vertex of a root-first path: the root 0; a vertex entered by a
    vertical edge 10; else 1 if its incoming edge differs in direction from its parent's,
    else 0 (the root has no incoming edge: its first child counts as straight)."""
    steps = [heading(a, b) for a, b in zip(path, path[1:])]
    out = [0]
    for i, h in enumerate(steps):
        if h is not None and h.vertical:
            out.append(WEIGHT_VERTICAL)
        elif i > 0 and steps[i - 1] is not h:
            out.append(WEIGHT_TURN)
        else:
            out.append(WEIGHT_STRAIGHT)
    return out


def path_cost(path: Sequence[Cell]) -> int:
    return sum(vertex_weights(path))


@dataclass
class H:
    """The directed graph H of a goal, with what its construction refused."""

    graph: nx.DiGraph
    goal: frozenset[Cell]
    first_column: int
    last_column: int
    refused: list[str] = field(default_factory=list)

    @property
    def marked(self) -> set[Cell]:
        return set(self.graph.nodes)

    def roots(self) -> list[Cell]:
        """Marked cells of G_1 (north first): where a substrate path can begin."""
        col = [c for c in self.graph.nodes if c.x == self.first_column]
        if self.first_column == self.last_column:
            return sorted(col, key=lambda c: -c.y)
        return sorted((c for c in col if self.graph.out_degree(c)), key=lambda c: -c.y)

    def children(self, v: Cell) -> list[Cell]:
        kids = list(self.graph.successors(v))
        return sorted(kids, key=lambda c: CHILD_ORDER.index(heading(v, c)))


def _vertical_ok(c: Cell, to: Cell, goal: frozenset[Cell], refused: list[str]) -> bool:
    north = to == Heading.N.of(c)
    name, rule = ("north", "2.2") if north else ("south", "2.3")
    for cell in corner_cells([c, to], 1, north):
        if cell in goal:
            refused.append(f"Definition {rule}(a): no {name} edge {c} -> {to}: {cell} is a goal "
                           "cell (Figure 4: X, Y, Z)")
            return False
    return True


def build_h(goal: frozenset[Cell] | set[Cell]) -> H:
    """H as section 4 builds it, columns east to west (the caller checked contiguity)."""
    goal = frozenset(goal)
    cols = columns(goal)
    xs = list(cols)
    g = nx.DiGraph()
    g.add_nodes_from(cols[xs[-1]])  # every node of G_m is marked
    h = H(g, goal, xs[0], xs[-1])
    for x in reversed(xs[:-1]):
        col = cols[x]  # north to south
        east = [c for c in col if Heading.NE.of(c) in goal or Heading.SE.of(c) in goal]
        top, bottom = col.index(east[0]), col.index(east[-1])
        for c in col[top:bottom + 1]:  # (B): edges to marked east neighbours
            for hd, bad in ((Heading.NE, Heading.S), (Heading.SE, Heading.N)):
                e = hd.of(c)
                if e not in g:
                    continue
                if bad.of(e) in g and g.has_edge(e, bad.of(e)):
                    h.refused.append(f"no {hd.value} edge {c} -> {e}: {e} continues "
                                     f"{bad.value} (an acute pocket, Definition 2)")
                    continue
                g.add_edge(c, e)
        for c in col[bottom + 1:]:  # (C), north to south: north edges
            n = Heading.N.of(c)
            if n in g and (g.out_degree(n) or n.x == h.last_column) and _vertical_ok(c, n, goal, h.refused):
                g.add_edge(c, n)
        for c in reversed(col[:top]):  # (A), south to north: south edges
            s = Heading.S.of(c)
            if s in g and (g.out_degree(s) or s.x == h.last_column) and _vertical_ok(c, s, goal, h.refused):
                g.add_edge(c, s)
        for c in col:
            if c in g and not g.out_degree(c):
                g.remove_node(c)  # nodes of (B) with no marked east neighbour stay unmarked
    return h


@dataclass(frozen=True)
class WeightedPath:
    cells: tuple[Cell, ...]
    cost: int


def traverse_graph(h: H, root: Cell) -> Iterator[WeightedPath]:
    """Figure 7 (TraverseGraph and Backtrack): every root-to-leaf path from ``root``.

    A vertex is black while it is on the path being walked; when the walk backs up past a
    vertex whose children are all done, the vertex turns white again, with its weight, so
    another parent can reach it (Figure 8's E and G). Each leaf visit yields the path and
    its cumulative weight. Iterative, so a long path needs no deep recursion.
    """
    weight: dict[Cell, int] = {root: 0}
    incoming: dict[Cell, Heading | None] = {root: None}
    path = [root]
    todo = [iter(h.children(root))]
    if not h.graph.out_degree(root):
        yield WeightedPath((root,), 0)
        return
    while todo:
        child = next(todo[-1], None)
        v = path[-1]
        if child is None:  # Backtrack: v's children are all done; unvisit v
            todo.pop()
            path.pop()
            weight.pop(v, None)
            incoming.pop(v, None)
            continue
        hd = heading(v, child)
        if hd.vertical:
            w = WEIGHT_VERTICAL
        elif incoming[v] is not None and incoming[v] is not hd:
            w = WEIGHT_TURN
        else:
            w = WEIGHT_STRAIGHT
        weight[child] = weight[v] + w
        incoming[child] = hd
        path.append(child)
        kids = h.children(child)
        if not kids:  # a leaf: the path's cost is the leaf's cumulative weight
            yield WeightedPath(tuple(path), weight[child])
            path.pop()
            weight.pop(child)
            incoming.pop(child)
        else:
            todo.append(iter(kids))

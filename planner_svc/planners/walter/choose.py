"""Choosing the substrate path (section 4, "Finding substrate paths", steps 1-3).

:func:`choose` looks at G in each of its six orientations whose columns are contiguous
north-south chains, builds H, walks every root-to-leaf path with TraverseGraph, and picks
the path of lowest cost that bisects G most evenly (cells north of the path against cells
south of it): paths of cost 0 and 1 first, if one comes within one module of bisecting G;
else any path, the most even first, then the cheapest. With I given (a scenario) only
paths that begin where I meets G are candidates; without, the intersection is chosen too
and I is laid as a straight chain west of it. A goal with no candidate raises
:class:`Inadmissible` with one line naming the condition that fails and where.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

from bus.errors import HexbenchError
from bus.lattice import Cell

from .frame import Heading, columns, contiguous_columns, heading, turn, unturn
from .graph import build_h, path_violation, traverse_graph

#: Headings to lay I along from the intersection (west of G: modules come in from G_1's
#: side); the one in line with the substrate path's first step is tried before these.
I_HEADINGS = (Heading.SW, Heading.NW, Heading.S, Heading.N)
#: Candidates whose round model is run before the choice settles on the best clean one.
MODEL_TRIES = 4


class Inadmissible(HexbenchError, ValueError):
    """A goal (or an I) the algorithm cannot reconfigure to; the message says why and where."""


@dataclass(frozen=True)
class Candidate:
    orientation: int
    path: tuple[Cell, ...]        # lattice cells, beginning with the intersection
    cost: int
    north: int                    # goal cells north of the path
    south: int

    @property
    def imbalance(self) -> int:
        return abs(self.north - self.south)

    @property
    def cost_class(self) -> str:
        return "0" if self.cost == 0 else "1" if self.cost == 1 else ">1"


@dataclass
class Choice:
    """The chosen substrate path, with I and what the round model predicts."""

    goal: frozenset[Cell]
    candidate: Candidate
    chain: list[Cell]             # I, free end first, the intersection last
    candidates: int               # admissible substrate paths seen (all orientations)
    rounds: int = 0
    moves: int = 0
    reached: bool = False
    collisions: list[str] = field(default_factory=list)
    world_refusals: list[str] = field(default_factory=list)
    #: the round model :func:`choose` ran for this choice, and its rules
    ran: tuple[str, Any] | None = field(default=None, repr=False, compare=False)

    @property
    def path(self) -> tuple[Cell, ...]:
        return self.candidate.path

    @property
    def orientation(self) -> int:
        return self.candidate.orientation

    @property
    def cost(self) -> int:
        return self.candidate.cost

    def model(self, rules: str = "hexbot"):
        """The round model of this choice; the one :func:`choose` ran if it ran one under these
        rules (its rounds are kept: running it again returns them; it took ~5 % of a 60-module
        run's wall time to run it twice)."""
        from .rounds import RoundModel
        if self.ran is not None and self.ran[0] == rules:
            return self.ran[1]
        return RoundModel(self.goal, self.chain, self.path, self.orientation, rules=rules)

    def summary(self) -> str:
        c = self.candidate
        return (f"substrate path {' '.join(map(str, c.path))} (orientation {c.orientation}, "
                f"{len(c.path)} cells); cost {c.cost}; splits G {c.north} north / {c.south} south; "
                f"I {self.chain[0]}..{self.chain[-1]}; rounds predicted {self.rounds}, "
                f"moves {self.moves}")


def _straight(chain: Sequence[Cell]) -> Heading | None:
    hs = {heading(a, b) for a, b in zip(chain, chain[1:])}
    return hs.pop() if len(hs) == 1 and None not in hs else None


def check_chain(goal: frozenset[Cell], chain: Sequence[Cell]) -> list[Cell]:
    """I as the algorithm needs it (free end first), or :class:`Inadmissible` saying why."""
    chain = list(chain)
    n = len(goal)
    if len(chain) != n:
        raise Inadmissible(f"I has {len(chain)} modules for {n} goal cells")
    if len(chain) > 1 and _straight(chain) is None:
        ordered = _order_chain(chain)
        if ordered is None:
            raise Inadmissible("I is not a straight chain (section 4 assumes one)")
        chain = ordered
    inside = [c for c in chain if c in goal]
    if len(inside) != 1:
        raise Inadmissible(f"I meets G in {len(inside)} cells "
                           f"({', '.join(map(str, inside)) or 'none'}); section 4 needs exactly one")
    if chain[0] == inside[0]:
        chain.reverse()
    if chain[-1] != inside[0]:
        raise Inadmissible(f"I meets G at {inside[0]}, which is not an end of I")
    return chain


def _order_chain(cells: Sequence[Cell]) -> list[Cell] | None:
    """The cells as one straight chain in order, if they are one."""
    for a in cells:
        for hd in Heading:
            line = [a]
            while len(line) < len(cells) and hd.of(line[-1]) in set(cells):
                line.append(hd.of(line[-1]))
            if len(line) == len(cells):
                return line
    return None


def _split(goal_t: frozenset[Cell], path_t: Sequence[Cell]) -> tuple[int, int]:
    top: dict[int, int] = {}
    bottom: dict[int, int] = {}
    for c in path_t:
        top[c.x] = max(top.get(c.x, c.y), c.y)
        bottom[c.x] = min(bottom.get(c.x, c.y), c.y)
    north = sum(1 for c in goal_t if c.y > top[c.x])
    south = sum(1 for c in goal_t if c.y < bottom[c.x])
    return north, south


def candidates(goal: Iterable[Cell], intersection: Cell | None = None
               ) -> tuple[list[Candidate], list[str]]:
    """Every admissible substrate path of G (all orientations), and per orientation why it
    gave none."""
    goal = frozenset(goal)
    out: list[Candidate] = []
    why: list[str] = []
    for k in range(6):
        goal_t = frozenset(turn(c, k) for c in goal)
        gap = contiguous_columns(goal_t)
        if gap is not None:
            x, y = gap
            why.append(f"orientation {k}: column {x - min(c.x for c in goal_t) + 1} is not one "
                       f"contiguous north-south chain (gap at {unturn(Cell(x, y), k)})")
            continue
        h = build_h(goal_t)
        roots = h.roots()
        if intersection is not None:
            c0 = turn(intersection, k)
            if c0.x != h.first_column:
                why.append(f"orientation {k}: Definition 3: I meets G at {intersection}, not in "
                           "the westernmost column G_1")
                continue
            if c0 not in roots:
                why.append(f"orientation {k}: Definition 4: no admissible substrate path begins "
                           f"at {intersection} ({_unmarked(h, k)})")
                continue
            roots = [c0]
        if not roots:
            why.append(f"orientation {k}: Definition 4: no admissible substrate path "
                       f"({_unmarked(h, k)})")
            continue
        for root in roots:
            for wp in traverse_graph(h, root):
                bad = path_violation(wp.cells, goal_t)
                if bad is not None:  # H admits only admissible paths; kept as a guard
                    why.append(f"orientation {k}: {bad}")
                    continue
                north, south = _split(goal_t, wp.cells)
                out.append(Candidate(k, tuple(unturn(c, k) for c in wp.cells), wp.cost,
                                     north, south))
    return out, why


def _unmarked(h, k: int) -> str:
    """Where H breaks: the easternmost column no substrate path can cross, and the first
    edge its construction refused there or in the column east of it."""
    import re
    cols = columns(h.goal)
    for x in reversed(list(cols)):
        if not any(c in h.graph for c in cols[x]):
            j = x - h.first_column + 1
            def source_x(r: str) -> int | None:
                m = re.search(r"\((-?\d+),(-?\d+)\) -> ", r)
                return int(m.group(1)) if m else None
            reasons = [r for r in h.refused if source_x(r) in (x, x + 1)]
            return (f"no cell of column G_{j} reaches G_m"
                    + (f"; {_lattice_text(reasons[0], k)}" if reasons else ""))
    return "no cell of G_1 has an edge"


def _lattice_text(reason: str, k: int) -> str:
    """A reason written in the orientation's cells, rewritten in lattice cells."""
    import re
    return re.sub(r"\((-?\d+),(-?\d+)\)",
                  lambda m: str(unturn(Cell(int(m.group(1)), int(m.group(2))), k)), reason)


def _rank(c: Candidate, preferred: bool) -> tuple:
    return (0 if preferred else 1, c.imbalance, c.cost, c.orientation)


def _lay_chain(goal: frozenset[Cell], c: Candidate) -> list[Cell] | None:
    c0_t = turn(c.path[0], c.orientation)
    goal_t = {turn(g, c.orientation) for g in goal}
    order = list(I_HEADINGS)
    if len(c.path) > 1:  # I in line with p's first step first: no corner at the intersection
        first = heading(c0_t, turn(c.path[1], c.orientation))
        back = Heading(list(Heading)[(list(Heading).index(first) + 3) % 6])
        if back in order:
            order.remove(back)
            order.insert(0, back)
    for hd in order:
        cells = [c0_t]
        for _ in range(len(goal) - 1):
            cells.append(hd.of(cells[-1]))
        if not any(x in goal_t for x in cells[1:]):
            return [unturn(x, c.orientation) for x in reversed(cells)]
    return None


def choose(goal: Iterable[Cell], chain: Sequence[Cell] | None = None,
           rules: str = "hexbot", model: bool = True) -> Choice:
    """The substrate path (and I) to reconfigure to ``goal``; :class:`Inadmissible` if none.

    The best-ranked candidates' round models are run (``model``) and the first that reaches
    the goal with every move legal is taken; if none is, the best-ranked one."""
    from .rounds import RoundModel

    goal = frozenset(goal)
    if not goal:
        raise Inadmissible("G is empty")
    if chain is not None:
        chain = check_chain(goal, chain)
    cands, why = candidates(goal, chain[-1] if chain else None)
    if not cands:
        good = [w for w in why if "contiguous" not in w]
        raise Inadmissible("inadmissible goal: " + (good or why)[0]
                           + f" (and in the other {len(why) - 1} orientations)" * (len(why) > 1))
    even = any(c.cost <= 1 and c.imbalance <= 1 for c in cands)
    ranked = sorted(cands, key=lambda c: _rank(c, even and c.cost <= 1 and c.imbalance <= 1))
    best: Choice | None = None
    for cand in ranked[:MODEL_TRIES]:
        i_chain = chain if chain is not None else _lay_chain(goal, cand)
        if i_chain is None:
            continue
        choice = Choice(goal, cand, list(i_chain), len(cands))
        if not model:
            return choice
        try:
            ran = RoundModel(goal, choice.chain, cand.path, cand.orientation, rules=rules)
            rep = ran.report()
            choice.ran = (rules, ran)
        except ValueError as exc:
            choice.collisions = [str(exc)]
        else:
            choice.rounds, choice.moves, choice.reached = rep.rounds, rep.moves, rep.reached
            choice.collisions, choice.world_refusals = rep.collisions, rep.world_refusals
        if best is None:
            best = choice
        if choice.reached and not choice.collisions and (rules == "paper" or not choice.world_refusals):
            return choice
    if best is None:
        raise Inadmissible("inadmissible goal: no straight chain I fits beside G at the start "
                           "of any admissible substrate path")
    return best

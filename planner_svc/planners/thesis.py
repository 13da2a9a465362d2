"""The thesis planner's five layers (Ch. 4, §4.3; Appendix C), as pure functions.

Each layer takes and returns sets of :class:`bus.lattice.Cell`. Behaviour follows the
spec (§10) and, where the spec leaves a choice, the thesis's Matlab functions; each
docstring states the reading taken. Ties are broken in the Matlab scan order
(``find`` walks a matrix column by column, top to bottom: x ascending, then y
descending) and neighbours are visited in side order 1..6 (``HexNeM``).

Layers:
  1. initial and goal configurations (given);
  2. :func:`electrons_and_voids` (``FindVE``), :func:`mobile_electrons` (``Mobile``),
     :func:`potential_voids` (``PV``);
  3. :func:`void_wave` (``HexVPT``), :func:`void_propagation` (``HexVP``);
  4. :func:`mdp_states`, :func:`mdp_actions`, :func:`mdp_rewards`,
     :func:`value_iteration`, :func:`next_location` (``MDP_*``);
  5. :func:`actuation` (``HexActuate``: Table 4-3 through :mod:`planner_svc.planners.rules`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Collection, Iterable

import numpy as np

from bus.lattice import Cell

from .rules import Move, articulation_cells, find_move, neighbours_xy, xy

GAMMA = 0.7            # discount factor chosen by the thesis (MDP_NRL, Table 4-2)
TOLERANCE = 0.001      # value iteration stops when no utility changes more than this
MAX_ITERATIONS = 500   # ... or after this many sweeps
REWARD_VOID = 1.0
REWARD_OTHER_ELECTRON = -1.0
REWARD_STEP = -0.04


def matlab_order(c: Cell) -> tuple[int, int]:
    """Sort key of Matlab's column-major scan of a thesis matrix: x up, then y down."""
    return (c.x, -c.y)


def _cells(cs: Iterable) -> frozenset[Cell]:
    return frozenset(Cell(*xy(c)) for c in cs)


def _neighbours(c: Cell) -> list[Cell]:
    return [Cell(*n) for n in neighbours_xy(xy(c))]


# --- layer 2 ------------------------------------------------------------------------------
def electrons_and_voids(current: Iterable[Cell], goal: Iterable[Cell]
                        ) -> tuple[frozenset[Cell], frozenset[Cell]]:
    """``FindVE``: electrons (modules outside the goal) and voids (goal cells without a module)."""
    cur, g = _cells(current), _cells(goal)
    return cur - g, g - cur


def mobile_electrons(electrons: Iterable[Cell], occupied: Iterable[Cell]) -> frozenset[Cell]:
    """``Mobile``: electrons with fewer than 4 occupied neighbours that are not articulation
    points of the occupancy graph (removing them keeps the structure connected)."""
    occ = {xy(c) for c in occupied}
    cut = articulation_cells(occ)
    out = set()
    for e in _cells(electrons):
        c = xy(e)
        if sum(n in occ for n in neighbours_xy(c)) < 4 and c not in cut:
            out.add(e)
    return frozenset(out)


def immobile_modules(occupied: Iterable[Cell], mobile: Iterable[Cell]) -> frozenset[Cell]:
    """Every module that is not a mobile electron (``I - ME`` in the Matlab)."""
    return _cells(occupied) - _cells(mobile)


def potential_voids(voids: Iterable[Cell], occupied: Iterable[Cell],
                    mobile: Iterable[Cell]) -> frozenset[Cell]:
    """``PV``: voids with at least one neighbour occupied by an immobile module."""
    imm = immobile_modules(occupied, mobile)
    return frozenset(v for v in _cells(voids) if any(n in imm for n in _neighbours(v)))


# --- layer 3 ------------------------------------------------------------------------------
def void_wave(occupied: Iterable[Cell], mobile: Iterable[Cell], void: Cell,
              obstacles: Iterable[Cell] = ()) -> list[tuple[Cell, int]]:
    """``HexVPT``: the mobile electrons a void's message reaches, with the time step.

    The message leaves ``void`` at time 0; at each time step every cell that got it
    in the previous step passes it to its neighbours. A neighbour takes part if it
    is not an immobile module (mobile electrons count as empty) and not an obstacle;
    it forwards the message only if it has an immobile substrate (a neighbouring
    immobile module). A mobile electron reached at time t is reported at t (once, the
    first time). Other potential voids forward the message too: the thesis text
    (§4.3.6 rule 4) excludes them, the Matlab does not; we follow the Matlab.
    Order: frontier cells in Matlab scan order, neighbours in side order.
    """
    imm = {xy(c) for c in immobile_modules(occupied, mobile)}
    me = {xy(c) for c in mobile}
    obst = {xy(c) for c in obstacles}
    start = xy(void)
    seen = {start}
    frontier = [start]
    found: list[tuple[Cell, int]] = []
    reached: set[tuple[int, int]] = set()
    t = 0
    while frontier and len(reached) < len(me):
        t += 1
        nxt: list[tuple[int, int]] = []
        for c in sorted(frontier, key=lambda p: (p[0], -p[1])):
            for n in neighbours_xy(c):
                if n in imm or n in obst:
                    continue
                if n in me and n not in reached:
                    reached.add(n)
                    found.append((Cell(*n), t))
                if n not in seen and any(k in imm for k in neighbours_xy(n)):
                    seen.add(n)
                    nxt.append(n)
        frontier = nxt
    return found


@dataclass(frozen=True)
class Pair:
    """A potential void matched to the mobile electron its wave reached first."""

    void: Cell
    electron: Cell
    time: int


def void_propagation(occupied: Iterable[Cell], goal: Iterable[Cell],
                     obstacles: Iterable[Cell] = ()) -> list[Pair]:
    """``HexVP``: match potential voids to mobile electrons, shortest wave time first.

    Each round, every unmatched potential void's wave names its first *unmatched*
    mobile electron; the void with the shortest time (ties: Matlab scan order) is
    paired and both leave the pool. Rounds continue while voids and electrons remain
    and some wave reaches an electron. (The Matlab recomputes the waves with all
    electrons and may hand one electron to two voids; the spec says one electron per
    void, which is what we do.)
    """
    occ = _cells(occupied)
    electrons, voids = electrons_and_voids(occ, goal)
    me = mobile_electrons(electrons, occ)
    pv = potential_voids(voids, occ, me)
    waves = {v: void_wave(occ, me, v, obstacles) for v in pv}
    free_v = sorted(pv, key=matlab_order)
    free_e = set(me)
    pairs: list[Pair] = []
    while free_v and free_e:
        best: Pair | None = None
        for v in free_v:
            hit = next(((e, t) for e, t in waves[v] if e in free_e), None)
            if hit and (best is None or hit[1] < best.time):
                best = Pair(v, hit[0], hit[1])
        if best is None:
            break
        pairs.append(best)
        free_v.remove(best.void)
        free_e.discard(best.electron)
    return pairs


# --- layer 4 ------------------------------------------------------------------------------
def mdp_states(occupied: Iterable[Cell], mobile: Iterable[Cell],
               obstacles: Iterable[Cell] = ()) -> frozenset[Cell]:
    """``MDP_State``: cells a mobile electron may occupy.

    With the mobile electrons lifted out (their cells count as empty), a state is a
    non-immobile, non-obstacle cell next to an immobile module with at most three
    immobile neighbours (the collision limit; the Matlab counts immobile neighbours
    only, so the electrons' own cells are states). The electrons' cells are added
    unconditionally, as the spec says.
    """
    imm = {xy(c) for c in immobile_modules(occupied, mobile)}
    obst = {xy(c) for c in obstacles}
    out: set[tuple[int, int]] = {xy(c) for c in mobile}
    for m in imm:
        for n in neighbours_xy(m):
            if n in imm or n in obst or n in out:
                continue
            if sum(k in imm for k in neighbours_xy(n)) <= 3:
                out.add(n)
    return frozenset(Cell(*c) for c in out)


def mdp_actions(states: Collection[Cell], s: Cell) -> list[Cell]:
    """``MDP_Action``: neighbouring states in side order, then staying at ``s``."""
    return [n for n in _neighbours(s) if n in states] + [s]


def mdp_rewards(states: Iterable[Cell], mobile: Iterable[Cell], electron: Cell,
                void: Cell) -> dict[Cell, float]:
    """``MDP_Reward``: +1 at the potential void, -1 at the other mobile electrons,
    -0.04 at every other state."""
    r = {s: REWARD_STEP for s in states}
    for e in mobile:
        if e != electron and e in r:
            r[e] = REWARD_OTHER_ELECTRON
    if void in r:
        r[void] = REWARD_VOID
    return r


@dataclass(frozen=True)
class ValueFunction:
    """Normalised utilities of the MDP states and how the iteration ended."""

    values: dict[Cell, float]
    iterations: int
    max_change: float

    def __getitem__(self, c: Cell) -> float:
        return self.values[c]


def value_iteration(rewards: dict[Cell, float], gamma: float = GAMMA, tol: float = TOLERANCE,
                    max_iterations: int = MAX_ITERATIONS) -> ValueFunction:
    """``MDP_VI``: U(s) = R(s) + gamma * max over actions U(s'), from U = 0.

    Deterministic transitions; actions are the moves of :func:`mdp_actions`. Sweeps
    are synchronous (numpy), stopping when the largest absolute change is below
    ``tol`` or after ``max_iterations`` sweeps; utilities are then divided by their
    maximum when it is positive. (The Matlab updates in place, tests the signed
    largest change, and only looks at the first three entries of its action list; we
    take the spec's reading: all actions, absolute change.)
    """
    states = sorted(rewards, key=matlab_order)
    if not states:
        return ValueFunction({}, 0, 0.0)
    index = {s: i for i, s in enumerate(states)}
    # Actions as an index table padded with "stay" so one numpy max covers all.
    acts = [[index[a] for a in mdp_actions(index, s)] for s in states]
    width = max(map(len, acts))
    table = np.array([a + [i] * (width - len(a)) for i, a in enumerate(acts)], dtype=np.intp)
    r = np.array([rewards[s] for s in states])
    u = np.zeros(len(states))
    change = 0.0
    n = 0
    for n in range(1, max_iterations + 1):
        new = r + gamma * u[table].max(axis=1)
        change = float(np.abs(new - u).max())
        u = new
        if change < tol:
            break
    top = u.max()
    if top > 0:
        u = u / top
    return ValueFunction({s: float(u[i]) for s, i in index.items()}, n, change)


def next_location(occupied: Iterable[Cell], goal: Iterable[Cell], electron: Cell, void: Cell,
                  obstacles: Iterable[Cell] = ()) -> tuple[Cell, ValueFunction]:
    """``MDP_NRL``: where the electron should go next, with the value function used.

    The neighbouring state with the highest utility if it beats staying (first in
    side order on ties); otherwise the electron's own cell. Only states are
    candidates: the Matlab also compares with non-state cells (utility 0), which can
    send an electron far from its void into an occupied cell.
    """
    occ = _cells(occupied)
    electrons, _ = electrons_and_voids(occ, goal)
    me = mobile_electrons(electrons, occ)
    states = mdp_states(occ, me, obstacles)
    vf = value_iteration(mdp_rewards(states, me, electron, void))
    best, best_u = electron, vf.values.get(electron, float("-inf"))
    for n in mdp_actions(states, electron)[:-1]:
        if vf.values[n] > best_u:
            best, best_u = n, vf.values[n]
    return best, vf


# --- layer 5 ------------------------------------------------------------------------------
def actuation(occupied: Iterable[Cell], current: Cell, nxt: Cell, fixed: Cell,
              obstacles: Iterable[Cell] = (), concurrent: Iterable[Move] = ()) -> Move | None:
    """``HexActuate``: the Table 4-3 rotation (joint, direction, substrate, released
    neighbour joints) taking ``current`` to ``nxt``, or None if no row is legal.

    Unlike the Matlab (which only checks the substrate and the three cells), the move
    must pass the full rule of :mod:`planner_svc.planners.rules`: free goal, connectivity,
    fixed module.
    """
    return find_move(occupied, current, nxt, fixed, obstacles, list(concurrent))

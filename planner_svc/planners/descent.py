"""Bound descent: moves that each lower the assignment bound, and window searches where
none does.

The assignment bound (:func:`planner_svc.planners.bounds.assignment_lower_bound`) changes by at
most one per move, since a move carries one module one cell. A plan whose every move
lowers it has exactly the bound's length; the bound's excess is what the other moves
cost. :func:`descend` builds such a plan from an optimal electron -> void assignment
(:class:`Assignment`), kept up to date move by move:

* **descending moves**: an electron steps nearer its void or into a void; a settled
  module steps into a void whose electron is nearer its cell (the electron will take
  that cell: a relay); or a settled module on a shortest line between an electron and
  its void steps out, the electron taking its cell and the module the void. Moves that
  make a void nearby unenterable (:func:`planner_svc.planners.moves.enterable`) or freeze an
  electron that could move are never made: they are the walls the relays otherwise
  dig through.
* **escapes** (enforced hill climbing): when no move descends, a best-first search in a
  window around each electron and void (:func:`planner_svc.planners.windows.window_search`)
  looks for the fewest rotations after which the bound of the pairs that meet the window
  is lower, by the same rules (no void near the window left unenterable, no electron
  frozen); the shortest one found is made, and the descent goes on. Only when no window
  has such an escape may one break those rules (without that second chance, the
  descent stopped with 12-21 voids left, where the relays did worse).
* **fills**: when no window has an escape at all and few voids are left
  (:data:`FILL_VOIDS`), a wider window around each void in turn, nearest pairs first,
  is searched for rotations after which it holds one electron and one void fewer
  (:func:`planner_svc.planners.windows.local_exchange`), the bound lower. The last voids are
  often walled in a few cells from their electrons, where the relays reach them by long
  chains or not at all.

It stops when the goal is reached, when neither an escape nor a fill is found, or when
its search allowance is spent. ``complete`` runs it first on large fleets whose voids
are near their electrons and lets the relays finish from where it stopped: the plans are
shorter than the relays' alone.

What each choice here gave when it was measured: docs/planner.md, *Measured for what
was kept*.
"""

from __future__ import annotations

from typing import Iterable

from .bounds import (assignment_cost, distance_matrix, electron_void_assignment,
                     min_cost_assignment)
from .moves import GOAL_OFFSET, Path, can_move, disk, enterable, is_cut, lone_steps, ring2
from .rules import Coord, MoveRule, hex_distance, neighbours_xy
from .shorten import moved, still_legal
from .windows import window_search, local_exchange

#: Window of an escape search: radius around an electron or void, and configurations
#: expanded per window (a larger budget finishes more often for about as many moves; no
#: other radius does better everywhere).
ESCAPE_RADIUS = 3
ESCAPE_BUDGET = 600
#: An escape this short is taken at once (the windows are searched shortest pairs first).
ESCAPE_ENOUGH = 2
#: Configurations all escape searches of one descent may price: enough for a descent that
#: goes far on a large fleet (with less it stops with voids left, and the plans are
#: longer); ``complete`` does not descend where voids are far from their electrons (Eden
#: blobs), which would spend it all and stop.
DESCENT_ALLOWANCE = 200_000
#: Pairs at most this far apart are looked at for settled modules stepping out of their
#: line (cells on a shortest line between them: a pair's parallelogram).
LINE_LIMIT = 8
#: Fills: window radius and configurations expanded around a void, and how many voids
#: may be left for them to be tried (the last voids need a wider window than an escape's
#: or a relay exchange's to be filled).
FILL_WINDOW = (5, 5000)
FILL_VOIDS = 8
#: A window the escape searches have not remembered (a remembered None is a failure).
_UNSEEN = object()


class Assignment:
    """An optimal assignment of electrons to voids by hex distance, and its cost (the
    assignment bound), updated in place by :meth:`apply` after each descending move.

    ``keep``: pairs to keep where an optimal assignment can (after an escape: ties are
    many, and a new assignment from scratch changed pairs far away, so the windows'
    remembered searches no longer applied)."""

    def __init__(self, occ: set[Coord], goal: set[Coord],
                 keep: dict[Coord, Coord] | None = None) -> None:
        electrons, voids = sorted(occ - goal), sorted(goal - occ)
        self.goal = goal
        self.cost = 0
        col: list[int] = []
        if electrons and keep:
            # Among the optimal assignments, the one keeping most pairs of ``keep``: the
            # cost scaled past any count of pairs, less one per pair kept.
            cost = distance_matrix(electrons, voids)
            scaled = cost * (len(electrons) + 1)
            column = {v: j for j, v in enumerate(voids)}
            for i, e in enumerate(electrons):
                j = column.get(keep.get(e))
                if j is not None:
                    scaled[i, j] -= 1
            col = [int(j) for j in min_cost_assignment(scaled)[0]]
            self.cost = int(sum(cost[i, j] for i, j in enumerate(col)))
        elif electrons:
            picked, total = electron_void_assignment(electrons, voids)
            col = [int(j) for j in picked]
            self.cost = int(round(total))
        self.void_of = {e: voids[j] for e, j in zip(electrons, col)}
        self.electron_of = {v: e for e, v in self.void_of.items()}

    def change(self, m: Coord, b: Coord) -> tuple[int, Coord | None]:
        """How moving the module at ``m`` to the free cell ``b`` changes the cost of an
        assignment made from this one by the cheapest single exchange, and the electron
        that exchange reassigns (None if none). A change of -1 is the most any move can
        do, so such an assignment is optimal again."""
        d = hex_distance
        if m not in self.goal:                          # an electron moves
            s = self.void_of[m]
            if b not in self.goal or b == s:
                return d(b, s) - d(m, s), None
            other = self.electron_of[b]                 # it takes another's void
            return d(other, s) - d(other, b) - d(m, s), other
        if b in self.goal:                              # a settled module fills a void
            other = self.electron_of[b]
            return d(other, m) - d(other, b), other
        # A settled module steps out: the new electron b and void m pair up, or some
        # electron takes m and b takes that electron's void.
        best, who = 1, None
        for e, s in self.void_of.items():
            delta = d(e, m) + d(b, s) - d(e, s)
            if delta < best:
                best, who = delta, e
        return best, who

    def apply(self, m: Coord, b: Coord, change: tuple[int, Coord | None]) -> None:
        """Move the module at ``m`` to ``b``, with the exchange :meth:`change` found."""
        void_of, electron_of, goal = self.void_of, self.electron_of, self.goal
        delta, other = change
        if m not in goal:
            s = void_of.pop(m)
            del electron_of[s]
            if b not in goal:
                void_of[b], electron_of[s] = s, b
            elif b != s:
                del electron_of[b]
                void_of[other], electron_of[s] = s, other
        elif b in goal:
            del electron_of[b]
            void_of[other], electron_of[m] = m, other
        elif other is None:
            void_of[b], electron_of[m] = m, b
        else:
            s = void_of[other]
            void_of[other], electron_of[m] = m, other
            void_of[b], electron_of[s] = s, b
        self.cost += delta


def descend(occ: set[Coord], goal: set[Coord], fixed: Coord,
            obstacles: set[Coord] | frozenset[Coord] = frozenset(),
            allowance: int = DESCENT_ALLOWANCE
            ) -> tuple[Path, list[tuple[int, int]], list[tuple[int, int]]]:
    """Descending moves, escapes and fills from ``occ`` (changed in place) towards
    ``goal``; returns the rotations made and where the escapes and the fills are among
    them (``(first move, moves)`` each; every other move lowers the bound by one).
    ``occ`` equals ``goal`` afterwards when the descent finished (see the module
    docstring)."""
    path: Path = []
    escapes: list[tuple[int, int]] = []
    fills: list[tuple[int, int]] = []
    memo: dict[tuple, Path | int | None] = {}
    fill_memo: dict[tuple, Path | None] = {}
    obstacles = set(obstacles)
    bound = Assignment(occ, goal)
    while bound.void_of:
        step = _descending_move(occ, goal, fixed, obstacles, bound)
        if step is not None:
            m, rule, b, change = step
            bound.apply(m, b, change)
            occ.discard(m)
            occ.add(b)
            path.append((m, rule))
            continue
        found, allowance = _escape(occ, goal, fixed, obstacles, bound, memo, allowance)
        if found is None:
            found, allowance = _escape(occ, goal, fixed, obstacles, bound, memo, allowance, False)
        made = escapes
        if found is None and allowance > 0:
            found, made = _fill(occ, goal, fixed, obstacles, bound, fill_memo), fills
        if found is None:
            break
        for m, b in _hops(found):
            occ.discard(m)
            occ.add(b)
        made.append((len(path), len(found)))
        path += found
        bound = Assignment(occ, goal, bound.void_of)
    return path, escapes, fills


def _descending_move(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
                     bound: Assignment
                     ) -> tuple[Coord, MoveRule, Coord, tuple[int, Coord | None]] | None:
    """The best safe move that lowers the bound by one: electron moves first, the
    electron farthest from its void first; then relays; then settled modules stepping
    out. ``(mobile, rule, goal cell, its change of the bound)`` or None."""
    best: tuple | None = None
    for m in sorted(_candidates(occ, goal, bound)):
        if m == fixed:
            continue
        steps = list(lone_steps(occ, m, obstacles))
        if not steps or is_cut(occ, m):
            continue
        for rule, b in steps:
            change = bound.change(m, b)
            if change[0] != -1:
                continue
            if m not in goal:
                rank = (0 if b not in goal or b == bound.void_of[m] else 1,
                        -hex_distance(m, bound.void_of[m]))
            else:
                rank = (2 if b in goal else 3, 0)
            if best is not None and rank >= best[0]:
                continue
            if _unsafe(occ, goal, m, b, obstacles):
                continue
            best = (rank, m, rule, b, change)
    return None if best is None else best[1:]


def _candidates(occ: set[Coord], goal: set[Coord], bound: Assignment) -> set[Coord]:
    """Modules whose move might lower the bound: electrons, settled modules next to a
    void, and settled modules on a shortest line between an electron and its void."""
    out = set(bound.void_of)
    for v in bound.electron_of:
        out.update(n for n in neighbours_xy(v) if n in occ)
    for e, v in bound.void_of.items():
        span = hex_distance(e, v)
        if 2 <= span <= LINE_LIMIT:
            out.update(c for c in disk(e, span - 1) if c in occ and c in goal
                       and hex_distance(c, v) + hex_distance(e, c) == span)
    return out


def _unsafe(occ: set[Coord], goal: set[Coord], m: Coord, b: Coord,
            obstacles: set[Coord]) -> bool:
    """Whether moving ``m`` to ``b`` leaves a void nearby unenterable that was not (the
    cell ``m`` leaves included), or an electron nearby (``b`` included) unable to move
    that could before."""
    after = set(occ)
    after.discard(m)
    after.add(b)
    return (_closes_void(occ, after, {*ring2(m), *ring2(b)}, goal, obstacles)
            or _freezes_electron(occ, after, {*ring2(b), b}, goal, obstacles))


def _escape(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
            bound: Assignment, memo: dict[tuple, Path | int | None], allowance: int,
            careful: bool = True) -> tuple[Path | None, int]:
    """The fewest rotations, in a window around some electron or void, after which the
    bound of the pairs meeting the window is lower (``careful``: by the rules of
    descending moves, :func:`_safe`); and what is left of ``allowance``. Windows are
    searched shortest pairs first; one of :data:`ESCAPE_ENOUGH` moves ends the search."""
    pair_of = {**bound.void_of, **bound.electron_of}
    centres = sorted(pair_of, key=lambda c: (hex_distance(c, pair_of[c]), c))
    best: Path | None = None
    for c in centres:
        if allowance <= 0:
            break
        window = set(disk(c, ESCAPE_RADIUS))
        pairs = frozenset((e, v) for e, v in bound.void_of.items()
                          if e in window or v in window)
        electrons_out = [e for e, _ in pairs if e not in window]
        voids_out = [v for _, v in pairs if v not in window]
        aim = sum(hex_distance(e, v) for e, v in pairs) - 1
        holes = goal & window
        # Cells a rotation in the window, and the enterability and mobility of the cells
        # within two of it, depend on.
        near = frozenset(x for x in disk(c, ESCAPE_RADIUS + 4) if x in occ)
        around = near - window
        seen: dict[frozenset[Coord], int] = {}

        def local(conf: frozenset[Coord]) -> int:
            got = seen.get(conf)
            if got is None:
                got = seen[conf] = assignment_cost(
                    electrons_out + [x for x in conf if x not in goal],
                    voids_out + [x for x in holes if x not in conf])
            return got

        def done(conf: frozenset[Coord], watch=disk(c, ESCAPE_RADIUS + 2)) -> bool:
            return local(conf) <= aim and (
                not careful or _safe(near, around | conf, watch, goal, obstacles))

        # Remembered by those cells and the pairs: most windows do not change between
        # escapes. How the rest connects may have, so a remembered path is checked again.
        # A failure under a cap is remembered as the cap.
        key = (c, near, pairs, careful)
        # Only an escape shorter than the best so far matters: the estimate is consistent
        # (a move changes the local bound by one at most), so the search stops there.
        cap = None if best is None else len(best) - 1
        kept = memo.get(key, _UNSEEN)
        if isinstance(kept, int):           # no escape of ``kept`` moves or fewer
            if cap is not None and cap <= kept:
                continue
            kept = _UNSEEN
        if kept is not _UNSEEN:
            found = kept
            if found is not None and not _playable(occ, found, fixed, obstacles):
                found = None
        else:
            found = window_search(
                occ, window, occ - window, c, ESCAPE_RADIUS, fixed, obstacles, done,
                lambda g, conf: g + max(0, local(conf) - aim), ESCAPE_BUDGET, None, (),
                cap=cap)
            memo[key] = found if found is not None or cap is None else cap
            allowance -= len(seen)      # the configurations it priced
        if found is not None and (best is None or len(found) < len(best)):
            best = found
            if len(best) <= ESCAPE_ENOUGH:
                break
    return best, allowance


def _fill(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
          bound: Assignment, memo: dict[tuple, Path | None]) -> Path | None:
    """Rotations in a window of :data:`FILL_WINDOW` around a void after which the window
    holds one electron and one void fewer and the bound is lower (so the descent still
    ends), voids nearest their electrons first; None if none of the voids has one or more
    than :data:`FILL_VOIDS` are left. ``memo``: the searches' (see
    :func:`planner_svc.planners.windows.local_exchange`)."""
    if len(bound.electron_of) > FILL_VOIDS:
        return None
    radius, budget = FILL_WINDOW
    pairs = sorted(bound.electron_of.items(), key=lambda ve: (hex_distance(*ve), ve))
    for v, _ in pairs:
        found = local_exchange(occ, goal, fixed, obstacles, v, radius, budget, memo)
        if found is None:
            continue
        after = moved(occ, _hops(found))
        if assignment_cost(after - goal, goal - after) < bound.cost:
            return found
    return None


def _safe(before: frozenset[Coord] | set[Coord], after: frozenset[Coord] | set[Coord],
          watch: Iterable[Coord], goal: set[Coord], obstacles: set[Coord]) -> bool:
    """Whether, of the cells ``watch``, every void unenterable ``after`` was an
    unenterable void ``before``, and every electron unable to move ``after`` was one
    ``before`` (the rules of descending moves, for a window's rotations)."""
    return not (_closes_void(before, after, watch, goal, obstacles)
                or _freezes_electron(before, after, watch, goal, obstacles))


def _closes_void(before: frozenset[Coord] | set[Coord], after: frozenset[Coord] | set[Coord],
                 watch: Iterable[Coord], goal: set[Coord], obstacles: set[Coord]) -> bool:
    """Whether a void of ``watch`` is unenterable ``after`` that was enterable, or
    occupied, ``before``."""
    return any(w in goal and w not in after and not enterable(after, w, obstacles)
               and (w in before or enterable(before, w, obstacles)) for w in watch)


def _freezes_electron(before: frozenset[Coord] | set[Coord],
                      after: frozenset[Coord] | set[Coord], watch: Iterable[Coord],
                      goal: set[Coord], obstacles: set[Coord]) -> bool:
    """Whether an electron of ``watch`` cannot move ``after`` that could, or was not
    there, ``before``."""
    return any(w in after and w not in goal and not can_move(after, w, obstacles)
               and (w not in before or can_move(before, w, obstacles)) for w in watch)


def _playable(occ: set[Coord], path: Path, fixed: Coord, obstacles: set[Coord]) -> bool:
    """Whether every rotation of ``path`` is legal in turn from ``occ`` (left unchanged)."""
    return still_legal(occ, _hops(path), fixed, obstacles)


def _hops(path: Path) -> list[tuple[Coord, Coord]]:
    """``path``'s rotations as (cell left, cell entered)."""
    return [(m, (m[0] + GOAL_OFFSET[rule][0], m[1] + GOAL_OFFSET[rule][1]))
            for m, rule in path]

"""The relays' last resort: holes dug open and refilled (:class:`Digging`, the
digging steps of :class:`planner_svc.planners.complete.relays.Heuristic`), lakes opened, and
walled-in electrons freed by a :func:`wedge`. See :mod:`planner_svc.planners.complete`."""

from __future__ import annotations

import itertools
from collections import deque
from typing import Callable, Iterable, Iterator

from ..moves import bfs, can_move, is_cut, walk
from ..plan import Plan, Problem
from ..rules import SIDE_OFFSETS, Coord, MoveRule, hex_distance, is_connected, neighbours_xy
from .walks import RELAY_LIMIT, layers

#: Hole digging (last resort, :meth:`Heuristic._hole_step`): planned fills per run,
#: most voids per hole (larger ones are lakes, opened instead), peels per hole beyond its
#: cells, least distance of a parking cell from the aimed hole cell, electrons tried per
#: hole cell (and shore modules per lake), modules tried per peel.
HOLE_CALLS = 24
HOLE_MAX = 12
HOLE_PEELS = 80
HOLE_PARK = 3
HOLE_ELECTRONS = 8
HOLE_TRY = 30
#: The crater is a hexagonal ball centred ``width`` cells beyond the open cell nearest
#: to the aimed hole cell, reaching ``deep`` cells past it; modules within
#: HOLE_PARK_GAP of it may peel too (a flat row peels from its end), and parking cells
#: are preferably farther. The ``(width, deep)`` of HOLE_CRATERS are tried in turn: a
#: hole a few cells deep in the bulk needs the wider, deeper balls (one whose face lies
#: along a flat surface ends flat, and which one does depends on the surface).
HOLE_CRATERS = ((3, 2), (5, 4), (8, 4))
HOLE_PARK_GAP = 3
#: When the crater's walls end flat, the peel goes nearest first
#: (:meth:`Heuristic._peel_nearest`): modules at most HOLE_REACH from a cell still to
#: peel, at most HOLE_NEAR_PEELS peels.
HOLE_REACH = 12
HOLE_NEAR_PEELS = 300
#: Parking cells the nearest-first peel prefers, tried in turn: any (0: the nearest), or
#: at least this far from the cells still to peel. Parked near, modules wall in the face
#: being eaten; parked far, they may block the way elsewhere, so a fill that fails with
#: one is tried with the next (holes a few cells deep in the bulk need it).
HOLE_PARK_FAR = (0, 10, 14)
#: The order the dig tries them in: the smallest craters first (the plans stay short).
HOLE_DIGS = (("crater", HOLE_CRATERS[0]), ("nearest", HOLE_PARK_FAR[0]),
             *(("crater", c) for c in HOLE_CRATERS[1:]),
             *(("nearest", f) for f in HOLE_PARK_FAR[1:]))
#: The last resort for a walled-in electron (:meth:`Heuristic._clear_wedge`): the relays
#: empty a 120-degree wedge of the structure at it, of at most WEDGE_MAX modules.
WEDGE_MAX = 200

def wedge(apexes: set[Coord], occ: set[Coord], side: int
          ) -> tuple[Callable[[Coord], bool], Callable[[Coord], int], list[Coord]]:
    """The 120-degree wedges at ``apexes`` that open between the directions d, d' of
    sides ``side`` and ``side + 2``, the cells apex + a*d + b*d' (a, b >= 0): a
    membership test, the level a + b of a cell (apex + a*d + b*d' for any apex: only
    differences count), and the modules of ``occ`` in them, highest level (farthest out)
    first, the apexes last.

    Taken away in that order, each module leaves with its neighbours farther out gone:
    those left lie in one arc of at most three (nearer the apex, or outside the wedge on
    its near side), so it can rotate and cuts nothing. Under a flat face that is the only
    way in (see ``docs/planner.md``): the wedge makes the apex a corner."""
    (ux, uy), (vx, vy) = SIDE_OFFSETS[side % 6], SIDE_OFFSETS[(side + 2) % 6]
    det = ux * vy - uy * vx                     # +-1: the two directions span the lattice

    def ab(c: Coord) -> tuple[int, int]:
        return (c[0] * vy - c[1] * vx) // det, (ux * c[1] - uy * c[0]) // det

    tips = [ab(t) for t in apexes]

    def inside(c: Coord) -> bool:
        a, b = ab(c)
        return any(a >= ta and b >= tb for ta, tb in tips)

    def level(c: Coord) -> int:
        return sum(ab(c))

    return inside, level, sorted((c for c in occ if inside(c)), key=lambda c: (-level(c), c))


class _Peel:
    """A simulated peel (:meth:`Heuristic._peel_plan`): the structure ``sim`` with the
    hole filled, the cells still to peel, and the walks so far."""

    def __init__(self, h: "Digging", hole: set[Coord], sim: set[Coord],
                 must: set[Coord]) -> None:
        self.ob, self.fixed = h.obstacles, h.fixed
        self.hole, self.sim = hole, sim
        self.left = set(hole) | set(must)
        self.peels: list[tuple[Coord, Coord]] = []
        self.parked: set[Coord] = set()
        self.hole_parks: set[Coord] = set()     # where the hole's own modules went

    def real(self) -> set[Coord]:
        """The structure the peel is played on: without the hole and its modules."""
        return self.sim - self.hole - self.hole_parks

    def movable(self, k: Coord, real: set[Coord]) -> bool:
        """Whether ``k`` can rotate and is no cut vertex, in ``sim`` and (unless a hole
        cell) in the real structure too: the crater is dug for real with the hole empty."""
        if k == self.fixed or k in self.hole_parks:
            return False
        if not can_move(self.sim, k, self.ob) or is_cut(self.sim, k):
            return False
        return k in self.hole or (can_move(real, k, self.ob) and not is_cut(real, k))

    def region(self, k: Coord, real: set[Coord]
               ) -> dict[Coord, tuple[int, Coord | None, MoveRule | None]]:
        """Where ``k`` can walk alone, in ``sim`` and (unless a hole cell) for real."""
        reg = bfs(self.sim - {k}, k, self.ob)
        if k not in self.hole:
            also = bfs(real - {k}, k, self.ob)
            reg = {c: v for c, v in reg.items() if c in also}
        return reg

    def peel_first(self, cands: list[tuple], real: set[Coord],
                   parks: Callable[[Coord, dict], list[tuple]]) -> bool:
        """Peel the first module of ``cands`` (keyed tuples ending in the cell, best first
        once sorted; at most :data:`HOLE_TRY` tried) that has a parking cell:
        ``parks(k, region)`` lists them as keyed tuples ending in the cell, best the least."""
        for *_, k in sorted(cands)[:HOLE_TRY]:
            options = parks(k, self.region(k, real))
            if options:
                self.take(k, min(options)[-1])
                return True
        return False

    def take(self, k: Coord, park: Coord) -> None:
        """Peel ``k`` to ``park``."""
        self.sim.discard(k)
        self.sim.add(park)
        self.parked.discard(k)
        self.parked.add(park)
        if k in self.hole:
            self.hole_parks.add(park)
        self.left.discard(k)
        self.peels.append((k, park))


class Digging:
    """The digging steps of the relay heuristic (mixed into
    :class:`planner_svc.planners.complete.relays.Heuristic`, whose constructor calls
    :meth:`_init_digging`)."""

    def _init_digging(self, hole_calls: int) -> None:
        """The digging state: ``hole_calls`` planned digs allowed (0: none)."""
        #: Planned hole fills left (:meth:`_hole_step`).
        self.hole_budget = hole_calls
        self.hole_failed: set[tuple[frozenset[Coord], ...]] = set()
        #: Cells (a hole, an electron) dug for before, whatever the outcome.
        self.dug_before: set[frozenset[Coord]] = set()
        #: The last lake opened (:meth:`_open_lake`), its crater's goal cells, and the
        #: voids left when it was opened (another lake opens only after progress). The
        #: relays read them too: voids at the mouth of an open lake wait.
        self.lake: set[Coord] = set()
        self.mouth: set[Coord] = set()
        self.lake_voids = 1 << 30
        #: The goal cells of the last wedge emptied (:meth:`_clear_wedge`) and their
        #: levels: refilled apex first, the peel backwards (else the apex is sealed).
        self.wedge_fill: dict[Coord, int] = {}

    def _hole_step(self) -> bool:
        """Fill a hole (a cluster of voids no walker reaches) by a planned dig (see
        :meth:`_fill_hole`), or open it if it is a lake (:meth:`_open_lake`). A hole that
        failed is tried again once the voids or the electrons have changed."""
        if self.hole_budget <= 0:
            return False
        occ, goal = self.occ, self.goal
        voids = self.goal - occ
        reach: set[Coord] = set()
        for e in sorted(occ - goal):
            if self._mobile(e):
                reach |= bfs(occ - {e}, e, self.obstacles).keys()
        # A failed dig leaves the structure as it was, and one that works returns: the
        # voids and electrons stay the same through both loops.
        these_voids, electrons = frozenset(voids), frozenset(occ - goal)
        done: set[Coord] = set()
        for t in sorted(voids - reach, key=lambda v: (-self.depth.get(v, 0), v)):
            if t in done:
                continue
            hole, todo = {t}, [t]
            while todo:
                for n in neighbours_xy(todo.pop()):
                    if n in voids and n not in hole and n not in reach:
                        hole.add(n)
                        todo.append(n)
            done |= hole
            # Retried when the electrons have moved (a dig that failed may work then).
            key = (frozenset(hole), these_voids, electrons)
            if key in self.hole_failed:
                continue
            if len(hole) > HOLE_MAX:
                if len(voids) >= self.lake_voids:
                    continue
                done_now = self._try_dig(key, lambda: self._open_lake(hole))
            else:
                done_now = self._try_dig(key, lambda: self._fill_hole(hole))
            if done_now is not None:
                return done_now
        # Electrons walled in (or reaching no void): dig each out the same way.
        for e in sorted(occ - goal, key=lambda c: (-self.depth.get(c, 0), c)):
            if self._mobile(e) and not voids.isdisjoint(bfs(occ - {e}, e, self.obstacles)):
                continue
            key = (frozenset({e}), these_voids)
            if key in self.hole_failed:
                continue
            before = set(occ)
            done_now = self._try_dig(key, lambda: self._fill_hole(set(), must={e}) and occ != before)
            # Once per cell per set of voids, even when it worked: freed electrons that
            # fill nothing get walled in again elsewhere, and the digs went round in circles.
            self.hole_failed.add(key)
            if done_now is not None:
                return done_now
        # Nothing else worked: a walled-in electron is freed by emptying a wedge at it.
        for e in sorted(occ - goal, key=lambda c: (-self.depth.get(c, 0), c)):
            key = (frozenset({e}), these_voids, "wedge")
            if key in self.hole_failed or self._mobile(e):
                continue
            done_now = self._try_dig(key, lambda: self._clear_wedge(e))
            self.hole_failed.add(key)
            if done_now is not None:
                return done_now
        return False

    def _clear_wedge(self, e: Coord) -> bool:
        """Free the walled-in electron at ``e`` by a detour: the relays play towards the
        goal with the goal cells of a :func:`wedge` at ``e`` traded for parking cells
        (:meth:`_detour_goal`), until ``e`` has left its cell. The smallest wedge first
        (at most :data:`WEDGE_MAX` modules, not the fixed one). The wedge's modules are
        peelable in order whatever its surface looks like, and the relays carry them past
        the notches of that surface, where lone walks to parking cells stop; afterwards
        the relays refill the wedge. False if no detour frees ``e`` (nothing moved)."""
        occ, fixed, ob = self.occ, self.fixed, self.obstacles
        wedges = []
        for side in range(6):
            inside, level, cells = wedge({e}, occ, side)
            if len(cells) <= WEDGE_MAX and not inside(fixed):
                wedges.append((len(cells), side, inside, level, cells))
        for *_, inside, level, cells in sorted(wedges, key=lambda w: w[:2]):
            detour = self._detour_goal(inside, set(cells))
            if detour is None:
                continue
            sub = Plan(self.plan.planner, Problem.of(occ, detour, fixed, ob, "wedge"))
            relays = type(self)(sub, advance=self.advance)
            relays.run(until=lambda: e not in relays.occ)
            if e in relays.occ:
                continue
            self.plan.steps += sub.steps
            occ.clear()
            occ |= relays.occ
            self.seen.add(frozenset(occ))
            self.wedge_fill = {c: level(c) for c in self.goal if inside(c)}
            return True
        return False

    def _detour_goal(self, inside: Callable[[Coord], bool], cells: set[Coord]
                     ) -> set[Coord] | None:
        """The goal without the cells ``inside`` a wedge (whose modules are ``cells``)
        and with as many parking cells, outside the goal and the wedge and touching none
        of its modules: a coat on the structure, nearest the wedge first (a second coat on
        the first if need be). A parking cell off the surface is hard to fill: clumps of
        them wall each other in. None if there are not enough, or the detour goal is not
        connected."""
        occ, ob = self.occ, self.obstacles
        keep = {c for c in self.goal if not inside(c)}
        need = len(occ) - len(keep)

        def ok(c: Coord) -> bool:
            return (c not in occ and c not in self.goal and c not in ob and not inside(c)
                    and not any(n in cells for n in neighbours_xy(c)))

        parks: set[Coord] = set()
        under = occ - cells
        while len(parks) < need:
            coat = sorted({n for c in under for n in neighbours_xy(c) if ok(n)} - parks,
                          key=lambda c: (min(hex_distance(c, w) for w in cells), c))
            if not coat:
                return None
            parks.update(coat[:need - len(parks)])
            under = parks
        detour = keep | parks
        return detour if is_connected(detour) else None

    def _open_lake(self, lake: set[Coord]) -> bool:
        """Open a hole too big to dig and refill (a *lake*) to the outside, for good: a
        crater from the open surface to the lake's shore module with the thinnest wall,
        its modules parked outside the goal (they become electrons; the crater's goal
        cells, voids the relays fill). False when no peel reaches it."""
        occ, ob = self.occ, self.obstacles
        lo = (min(x for x, _ in occ) - 2, min(y for _, y in occ) - 2)
        hi = (max(x for x, _ in occ) + 2, max(y for _, y in occ) + 2)
        outside, todo = {lo}, deque([lo])
        while todo:
            c = todo.popleft()
            for n in neighbours_xy(c):
                if (lo[0] <= n[0] <= hi[0] and lo[1] <= n[1] <= hi[1] and n not in occ
                        and n not in ob and n not in outside):
                    outside.add(n)
                    todo.append(n)
        # Wall thickness: breadth-first steps through modules from the outside.
        depth = layers(occ, {n for c in outside for n in neighbours_xy(c) if n in occ})
        shore = sorted({n for v in lake for n in neighbours_xy(v) if n in depth},
                       key=lambda c: (depth[c], c))
        before = len(self.goal - occ)
        for target in shore[:HOLE_ELECTRONS]:
            if target == self.fixed:
                continue
            for peels in self._peel_plans(set(), must={target}):
                if self._or_undo(lambda: all(self._walk_to(k, park) for k, park in peels)):
                    self.lake, self.lake_voids = set(lake), before
                    self.mouth = {k for k, _ in peels} & self.goal
                    return True
        return False

    def _or_undo(self, attempt: Callable[[], bool]) -> bool:
        """Run ``attempt`` (which plays moves); if it returns False, undo its moves."""
        mark, saved, seen = len(self.plan.steps), set(self.occ), set(self.seen)
        if attempt():
            return True
        del self.plan.steps[mark:]
        self.occ.clear()
        self.occ |= saved
        self.seen = seen
        return False

    def _try_dig(self, key, attempt) -> bool | None:
        """Run one dig ``attempt``; roll the plan back if it fails. True: it worked;
        False: the dig budget is spent; None: try the next hole."""
        self.hole_budget -= 1
        if self._or_undo(attempt):
            return True
        self.hole_failed.add(key)
        return False if self.hole_budget <= 0 else None

    def _fill_hole(self, hole: set[Coord], must: set[Coord] = frozenset()) -> bool:
        """Dig ``hole`` open and fill it, as the reverse of a peel (also digs out the
        electrons of ``must``, whose cells stay empty).

        :meth:`_peel_plan` peels the structure with the hole filled. Then for real:
        the crater's modules walk to their parking cells in that order, and the peel is
        undone backwards: a crater module walks back from a parking cell into a goal
        cell, a hole cell takes an electron that reaches it or else a waiting crater
        module (the outermost crater cell then stays a void on the surface for the
        relays). Each walk is searched on the current structure; False (the caller rolls
        back) when one is impossible. Once the hole is filled a failed walk back ends the
        fill early, with success: the relays refill the rest of the crater.
        """
        # A hole's first dig takes the first peel it finds (short plans); once one has
        # failed, the next digs of the same cells try every peel in turn.
        cells = frozenset(hole | must)
        plans: Iterable[list[tuple[Coord, Coord]]]
        if cells not in self.dug_before:
            self.dug_before.add(cells)
            plans = itertools.islice(self._peel_plans(hole, must=must, digs=HOLE_DIGS[:2]), 1)
        else:
            plans = self._peel_plans(hole, must=must)
        return any(self._or_undo(lambda: self._dig_and_fill(hole, peels)) for peels in plans)

    def _dig_and_fill(self, hole: set[Coord], peels: list[tuple[Coord, Coord]]) -> bool:
        """Play one planned peel of :meth:`_fill_hole` for real; False when a walk is
        impossible (the caller rolls back)."""
        occ, goal, fixed = self.occ, self.goal, self.fixed
        for k, park in peels:                       # dig the crater
            if k in hole:
                continue
            if not self._walk_to(k, park):
                return False
        # Crater goal cells in the order they were emptied (the first is the outermost,
        # the last to be refilled); modules are interchangeable: any waiting one may
        # go back to a cell, its own first.
        back = [k for k, _ in peels if k not in hole and k in goal]
        waiting: list[Coord] = []       # where the crater's modules wait (a parked
        for k, park in peels:           # module may have been moved on, farther)
            if k in hole:
                continue
            if k in waiting:
                waiting.remove(k)
            waiting.append(park)
        lent: set[Coord] = set()        # crater cells left empty (their module filled
        for k, park in reversed(peels):     # the hole); fill deepest first
            if k not in hole:
                if k in goal and k not in lent:
                    order = ([park] if park in waiting else []) + waiting[::-1]
                    for p in order:
                        if self._walk_to(p, k):
                            waiting.remove(p)
                            break
                    else:
                        # The hole is filled: the relays refill the rest of the crater.
                        return not (hole - self.occ)
                continue
            es = sorted((hex_distance(e, k), e) for e in occ - goal
                        if e not in waiting and e != fixed)
            if any(self._walk_to(e, k) for _, e in es[:HOLE_ELECTRONS]):
                continue
            # No electron reaches it: a waiting crater module fills it instead, and
            # the outermost crater cell stays a void on the surface.
            for p in waiting[::-1]:
                if self._walk_to(p, k):
                    waiting.remove(p)
                    spare = [c for c in back if c not in lent]
                    if spare:       # else it was an electron of the crater anyway
                        lent.add(spare[0])
                    break
            else:
                return False
        return True

    def _peel_plan(self, hole: set[Coord], sim: set[Coord] | None = None,
                   must: set[Coord] = frozenset()) -> list[tuple[Coord, Coord]] | None:
        """The peel of :meth:`_fill_hole`, simulated: ``(cell, parking cell)`` per
        walk, or None; every cell of ``hole`` and ``must`` gets peeled. ``sim`` is the
        structure with the hole filled (the default).

        A crater first (:meth:`_peel_crater`); when its walls end flat, peeling nearest
        first (:meth:`_peel_nearest`). The first of :meth:`_peel_plans`."""
        return next(self._peel_plans(hole, sim, must), None)

    def _peel_plans(self, hole: set[Coord], sim: set[Coord] | None = None,
                    must: set[Coord] = frozenset(), digs: tuple = HOLE_DIGS
                    ) -> Iterator[list[tuple[Coord, Coord]]]:
        """The peels :meth:`_fill_hole` tries in turn (see :meth:`_peel_plan`), in the
        order of ``digs`` (:data:`HOLE_DIGS`: the craters of :data:`HOLE_CRATERS` and the
        nearest-first peels with the parking preferences of :data:`HOLE_PARK_FAR`), only
        those that peel every cell."""
        sim = self.occ | hole if sim is None else sim
        for how, arg in digs:
            pl = _Peel(self, hole, set(sim), must)
            peels = (self._peel_crater(pl, *arg) if how == "crater"
                     else self._peel_nearest(pl, arg))
            if peels is not None:
                yield peels

    def _peel_crater(self, pl: _Peel, width: int = HOLE_CRATERS[0][0],
                     deep: int = HOLE_CRATERS[0][1]) -> list[tuple[Coord, Coord]] | None:
        """Aim at the cell still to peel nearest to an open free cell (at most two occupied
        neighbours) and dig the crater (see :data:`HOLE_CRATERS`) outermost first: each
        peel is a movable module (:meth:`_Peel.movable`) walking to the nearest parking
        cell outside the goal and the crater, preferably not next to another parked
        module. Bounded by :data:`HOLE_PEELS`."""
        goal, ob = self.goal, self.obstacles
        sim, left, hole = pl.sim, pl.left, pl.hole
        aim: Coord = (1 << 30, 0)       # not a hole cell: chosen in the first round
        centre, span = aim, 0
        for _ in range(HOLE_PEELS + len(hole)):
            if not left:
                break
            if aim not in left:         # the next hole cell to dig to
                rim = {n for c in sim for n in neighbours_xy(c)
                       if n not in sim and n not in ob and n not in hole}
                opens = [c for c in rim if sum(n in sim for n in neighbours_xy(c)) <= 2]
                if not opens:
                    return None
                aim, mouth = min(((h, c) for h in (left & hole or left) for c in opens),
                                 key=lambda hc: (hex_distance(*hc), hc))
                # The crater: a hexagonal ball about a centre beyond the mouth, touching
                # the aim (its walls open at 120 degrees or more, so modules peel).
                ln = hex_distance(aim, mouth)
                f = (ln + width) / ln
                centre = (round(aim[0] + (mouth[0] - aim[0]) * f),
                          round(aim[1] + (mouth[1] - aim[1]) * f))
                span = hex_distance(aim, centre) + deep
            real = pl.real()
            cands = []
            for k in sim:
                dk = hex_distance(k, centre)
                # Outside the crater only near it: the end of a flat row peels first.
                if k not in left and dk > span + HOLE_PARK_GAP:
                    continue
                if pl.movable(k, real):
                    cands.append((k not in left, dk > span, dk, k))

            def parks(k: Coord, reg: dict) -> list[tuple]:
                # Parking cells outside the crater, preferably not on its rim, apart from
                # the other parked modules (each can leave again, in any order, and no
                # notch forms between them).
                dk = hex_distance(k, centre)
                return [(hex_distance(c, centre) <= span + HOLE_PARK_GAP,
                         any(hex_distance(c, q) <= 2 for q in pl.parked if q != k), reg[c][0], c)
                        for c in reg if c not in goal and c not in hole
                        and hex_distance(c, centre) > max(span, dk)
                        and hex_distance(c, aim) >= HOLE_PARK]
            if not pl.peel_first(cands, real, parks):
                return None
        return None if left else pl.peels

    def _peel_nearest(self, pl: _Peel, far: int = 0) -> list[tuple[Coord, Coord]] | None:
        """Peel the movable module nearest to a cell still to peel (within
        :data:`HOLE_REACH`), modules not yet moved first, to the nearest parking cell
        outside the goal that is farther from those cells, preferably not next to another
        parked module and, if ``far``, at least ``far`` from those cells. A flat face only
        rotates at its ends (its other modules have four neighbours), so a crater ending in
        one is stuck; this peels the face from its end inwards (Eden blobs of 1000 modules:
        walled-in electrons in a bay's flat ceiling). Bounded by :data:`HOLE_NEAR_PEELS`."""
        goal = self.goal
        sim, left, hole = pl.sim, pl.left, pl.hole
        # Distances to the cells still to peel, kept until one is peeled (``left`` only
        # shrinks): each round asks again for most of the structure and its regions.
        gaps_for, known = len(left), {}

        def gap(c: Coord) -> int:
            nonlocal gaps_for
            if gaps_for != len(left):
                gaps_for = len(left)
                known.clear()
            d = known.get(c)
            if d is None:
                d = known[c] = min(hex_distance(c, a) for a in left)
            return d

        for _ in range(HOLE_NEAR_PEELS):
            if not left:
                return pl.peels
            real = pl.real()
            cands = []
            for k in sim:
                dk = gap(k)
                if dk <= HOLE_REACH and pl.movable(k, real):
                    cands.append((k not in left, k in pl.parked, dk, k))

            def parks(k: Coord, reg: dict) -> list[tuple]:
                dk = gap(k)
                gaps = {c: gap(c) for c in reg if c not in goal and c not in hole}
                return [(any(hex_distance(c, q) <= 1 for q in pl.parked if q != k),
                         g < far, reg[c][0], c)
                        for c, g in gaps.items() if g >= HOLE_PARK and g > dk]
            if not pl.peel_first(cands, real, parks):
                return None
        return None if left else pl.peels

    def _walk_to(self, m: Coord, target: Coord) -> bool:
        """Walk the module at ``m`` alone to ``target`` if it can leave and reach it."""
        occ, ob = self.occ, self.obstacles
        if m not in occ or target in occ or m == self.fixed:
            return False
        if not can_move(occ, m, ob) or is_cut(occ, m):
            return False
        path = walk(occ - {m}, m, {target}, ob, limit=RELAY_LIMIT * 4)
        if not path:
            return False
        self._do_walk(path)
        return True

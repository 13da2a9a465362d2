"""Window searches: best-first searches for rotations inside a disk (the *window*) while
the rest of the structure stays still.

``complete`` uses them where its relays find no chain: to fill a blocked void or free a
trapped electron (:func:`local_repair`), to trade a void for an electron a few cells away
(:func:`local_exchange`) and to bring electrons nearer the voids along the surface
(:func:`local_advance`); :mod:`planner_svc.planners.shorten` uses their successors
(:func:`window_moves`) to re-plan stretches of a finished plan. A rotation inside the
window depends on the cells within two of it only, and whether a module is a cut vertex
on how the still part's components meet the window, so a search costs what the window
costs, whatever the size of the structure.
"""

from __future__ import annotations

import heapq
from collections import Counter, deque
from typing import Callable

from .moves import ONE_ARC, Path, ring_mask, disk, lone_steps, ring2
from .rules import Coord, MoveRule, hex_distance, neighbours_xy
from .exact import best_first

#: How much a local advance must lower the window's electrons' surface distances.
ADVANCE_GAIN = 2
#: Surface distance counted at most per electron in a local advance (far is far).
ADVANCE_CAP = 50
#: Surface distance of a cell the surface field does not reach.
FAR = 10 ** 4
#: Weight of the remaining defects against moves made in the local repair search.
REPAIR_WEIGHT = 3


def local_repair(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
                 target: Coord, radius: int, budget: int,
                 memo: dict[tuple, Path | None] | None = None) -> Path | None:
    """Best-first search for a short sequence of rotations, inside a window of ``radius``
    around ``target``, that fills a blocked void at ``target`` (or empties a trapped
    electron's cell) while every settled goal cell of the window stays occupied, except
    at most one on the surface.

    This digs a pocket open and closes it again behind the new module: the vacancy
    moves out to the surface, where relays can fill it. The rest of the structure stays
    still, so connectivity is checked on the whole of it. ``memo``: see
    :func:`window_search` (near the window, ``goal`` must be the same at every call
    with it, or decided by the structure there).
    """
    window = set(disk(target, radius))
    outside = occ - window
    start = frozenset(occ & window)
    keep = start & goal
    fill = target not in occ
    surface = {c for c in keep if c != fixed and c != target
               and any(n not in occ and n not in goal for n in neighbours_xy(c))}

    def missing(conf: frozenset[Coord]) -> int:
        miss = keep - conf
        return len(miss) if len(miss) != 1 or not miss <= surface else 0

    def score(conf: frozenset[Coord]) -> int:
        return ((target not in conf) if fill else (target in conf)) + missing(conf)

    # Weighted: the score counts cells, a repair needs several moves each.
    return window_search(occ, window, outside, target, radius, fixed, obstacles,
                          lambda conf: score(conf) == 0,
                          lambda g, conf: g + REPAIR_WEIGHT * score(conf), budget,
                          memo, ("repair",))


def window_moves(window: set[Coord], outside: set[Coord], fixed: Coord,
                 obstacles: set[Coord], components: _Components | None = None):
    """Successors for a search inside ``window`` with the structure ``outside`` it still:
    every legal rotation of a module of the window to a cell of the window.

    A module's rotations depend on the cells within two of it only, so a configuration's
    table of them (module -> rotations into the window) is its parent's with the modules
    near the two cells that changed looked up again (the searches spent most of their
    time here)."""
    is_cut_in = _window_cuts(window, outside, components)
    tables: dict[frozenset[Coord], dict[Coord, list[tuple[MoveRule, Coord]]]] = {}
    #: A configuration generated and not yet expanded -> (its parent, cell left, cell entered).
    made: dict[frozenset[Coord], tuple[frozenset[Coord], Coord, Coord]] = {}

    def rotations(full: set[Coord], m: Coord) -> list[tuple[MoveRule, Coord]]:
        if m == fixed:
            return []
        # full holds m: no cell checked is m.
        return [(rule, d) for rule, d in lone_steps(full, m, obstacles) if d in window]

    # One structure for every configuration: the window's cells are set to each in turn
    # (a union with the ~1000 cells outside per configuration cost more than the rest).
    # Searches take all of a configuration's successors before asking for the next's.
    full = set(outside)
    shown: list[frozenset[Coord]] = [frozenset()]

    def successors(conf: frozenset[Coord]):
        for c in shown[0] ^ conf:
            if c in conf:
                full.add(c)
            else:
                full.discard(c)
        shown[0] = conf
        link = made.pop(conf, None)
        if link is None:
            table = {m: rotations(full, m) for m in conf}
        else:
            parent, left, entered = link
            table = dict(tables[parent])
            del table[left]
            table[entered] = rotations(full, entered)
            for c in {*ring2(left), *ring2(entered)}:
                if c in conf:
                    table[c] = rotations(full, c)
        tables[conf] = table
        for m in conf:
            steps = table[m]
            if not steps or is_cut_in(conf, full, m):
                continue
            rest = conf - {m}
            for rule, d in steps:
                nxt = rest | {d}
                if nxt not in tables:
                    made.setdefault(nxt, (conf, m, d))
                yield m, rule, nxt
    return successors


#: The still part of a window search: cell -> component, and each component's *ports*
#: (the window cells next to it).
_Components = tuple[dict[Coord, int], list[set[Coord]]]


def _still_components(window: set[Coord], outside: set[Coord]) -> _Components:
    """The connected components of ``outside`` that meet ``window`` (a disk), and their
    ports into it: labels for the cells of ``outside`` next to the window at least,
    which are all the cut tests and ports look at.

    Each search walks the structure nearest the window first and stops once every cell
    next to the window has its label: it goes round the window rather than through
    the whole structure (bound descent on blobs of 1000 modules: a third of its time went
    to labelling every cell)."""
    n = len(window)
    centre = (round(sum(c[0] for c in window) / n), round(sum(c[1] for c in window) / n))
    rim = {m for c in window for m in neighbours_xy(c) if m in outside}
    label: dict[Coord, int] = {}
    ports: list[set[Coord]] = []
    left = len(rim)
    for r in sorted(rim):
        if r in label:
            continue
        k = len(ports)
        label[r] = k
        left -= 1
        todo = [(0, r)]
        while todo and left:
            _, c = heapq.heappop(todo)
            for m in neighbours_xy(c):
                if m in outside and m not in label:
                    label[m] = k
                    if m in rim:
                        left -= 1
                    heapq.heappush(todo, (hex_distance(m, centre), m))
        ports.append(set())
    for r in rim:
        ports[label[r]].update(m for m in neighbours_xy(r) if m in window)
    return label, ports


def _window_cuts(window: set[Coord], outside: set[Coord], components: _Components | None = None
                 ) -> Callable[[frozenset[Coord], set[Coord], Coord], bool]:
    """``is_cut(conf, full, m)`` for the structure ``full = outside | conf``, ``conf`` inside
    ``window`` and ``outside`` still: exact, and as quick as a search of the window.

    The still part's connected components (:func:`_still_components`) are found once,
    at the first test that needs them; a search from a neighbour of ``m`` then crosses
    each component in one step, entering the window again at its ports (on a blob of
    1000 modules, a plain search around the window explores hundreds of cells per
    test). Most tests need none: the ring around ``m`` is one arc (and the searches that
    re-plan windows mostly stop within a few configurations)."""
    label: dict[Coord, int] = {}
    ports: list[set[Coord]] = []
    if components:
        label, ports = components
    ready = [components is not None]

    around: dict[Coord, list[Coord]] = {}

    def is_cut_in(conf: frozenset[Coord], full: set[Coord], m: Coord) -> bool:
        """Whether ``m`` is a cut vertex of ``full`` (``outside | conf``)."""
        if ONE_ARC[ring_mask(full, *m)]:
            return False
        if not ready[0]:
            new_label, new_ports = _still_components(window, outside)
            label.update(new_label)
            ports.extend(new_ports)
            ready[0] = True
        # A node is a cell of ``conf`` or the label of a still component (inlined: the
        # searches make millions of these steps).
        want: set[Coord | int] = set()
        for c in neighbours_xy(m):
            n = c if c in conf else label.get(c)
            if n is not None:
                want.add(n)
        first = want.pop()
        seen = {first, m}
        todo = [first]
        while todo and want:
            a = todo.pop()
            if a.__class__ is int:
                cells = ports[a]
            else:
                cells = around.get(a)
                if cells is None:
                    cells = around[a] = neighbours_xy(a)
            for c in cells:
                n = c if c in conf else label.get(c)
                if n is not None and n not in seen:
                    seen.add(n)
                    want.discard(n)
                    todo.append(n)
        return bool(want)
    return is_cut_in


def local_exchange(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
                   center: Coord, radius: int, budget: int,
                   memo: dict[tuple, Path | None] | None = None) -> Path | None:
    """Best-first search, inside a window of ``radius`` around ``center``, for rotations
    after which the window holds one electron and one void fewer (an electron of the
    window has, directly or through settled modules moving aside and back, filled a void
    of the window). The rest of the structure stays still.

    Where the relays find no chain the trouble is often local: the electron is walled in
    and the void sits behind a notch a few cells away; here they trade places.
    ``memo``: see :func:`window_search` (the same ``goal`` at every call with it).
    """
    window = set(disk(center, radius))
    outside = occ - window
    start = frozenset(occ & window)
    want = goal & window

    def defects(conf: frozenset[Coord]) -> int:
        return len(want - conf) + len(conf - goal)

    def estimate(conf: frozenset[Coord]) -> int:
        # defects(conf), weighted, plus how far the window's electrons are from its voids.
        extra, holes = conf - goal, want - conf
        gap = sum(min(hex_distance(v, e) for e in extra) for v in holes) if extra else 0
        return REPAIR_WEIGHT * (len(holes) + len(extra)) + gap

    goal_defects = defects(start) - 2
    return window_search(occ, window, outside, center, radius, fixed, obstacles,
                          lambda conf: defects(conf) <= goal_defects,
                          lambda g, conf: g + estimate(conf), budget, memo, ("exchange",))


def surface_field(occ: set[Coord], voids: set[Coord],
                  obstacles: set[Coord] | frozenset[Coord] = frozenset()) -> dict[Coord, int]:
    """Distance from the voids along the surface: breadth-first over free cells that
    touch the structure (where walkers roll), from every void at once."""
    field = dict.fromkeys(voids, 0)
    todo = deque(voids)
    while todo:
        c = todo.popleft()
        for n in neighbours_xy(c):
            if (n not in field and n not in occ and n not in obstacles
                    and any(m in occ for m in neighbours_xy(n))):
                field[n] = field[c] + 1
                todo.append(n)
    return field


def surface_distance(field: dict[Coord, int]) -> Callable[[Coord], int]:
    """``cell -> distance`` over a :func:`surface_field`; an occupied cell counts from its
    nearest free neighbour, a cell out of the field is :data:`FAR`."""
    known: dict[Coord, int] = {}

    def dist(c: Coord) -> int:
        if c in field:
            return field[c]
        d = known.get(c)
        if d is None:
            d = known[c] = min(FAR, min(field.get(n, FAR) for n in neighbours_xy(c)) + 1)
        return d
    return dist


def local_advance(occ: set[Coord], goal: set[Coord], fixed: Coord, obstacles: set[Coord],
                  centre: Coord, radius: int, budget: int, dist: Callable[[Coord], int],
                  seen: set[frozenset[Coord]], memo: dict[tuple, Path | None] | None = None
                  ) -> Path | None:
    """Best-first search, inside a window of ``radius`` around the electron at
    ``centre``, for rotations that bring the window's electrons :data:`ADVANCE_GAIN`
    nearer the voids in total (``dist``: :func:`surface_distance`, capped at
    :data:`ADVANCE_CAP` each) without emptying a goal cell or repeating a configuration
    of ``seen``. Settled modules may step aside and back: an electron stopped by a notch
    gets past it. ``memo``: see :func:`window_search` (the same ``goal`` at every call
    with it); only failures are kept, since ``seen`` grows."""
    cells = disk(centre, radius)
    window = set(cells)
    outside = occ - window
    start = frozenset(occ & window)
    want = goal & window
    missing = want - start

    def potential(conf: frozenset[Coord]) -> int:
        return sum(min(dist(c), ADVANCE_CAP) for c in conf - goal)

    aim = potential(start) - ADVANCE_GAIN
    # ``seen`` holds whole configurations: a failure it decided is not the window's alone.
    refused = []

    def done(conf: frozenset[Coord]) -> bool:
        if want - conf <= missing and potential(conf) <= aim:
            if frozenset(outside | conf) not in seen:
                return True
            refused.append(conf)
        return False

    def priority(g: int, conf: frozenset[Coord]) -> int:
        return g + REPAIR_WEIGHT * len(want - conf - missing) + max(0, potential(conf) - aim)

    far = tuple(min(dist(c), ADVANCE_CAP) for c in cells)
    return window_search(occ, window, outside, centre, radius, fixed, obstacles, done,
                          priority, budget, memo, ("advance", far), lambda: not refused,
                          keep_found=False)


def window_search(occ: set[Coord], window: set[Coord], outside: set[Coord], centre: Coord,
                   radius: int, fixed: Coord, obstacles: set[Coord],
                   is_goal: Callable[[frozenset[Coord]], bool],
                   priority: Callable[[int, frozenset[Coord]], int], budget: int,
                   memo: dict[tuple, Path | None] | None, tag: tuple,
                   exact: Callable[[], bool] = lambda: True, keep_found: bool = True,
                   cap: float | None = None) -> Path | None:
    """Best-first search (:func:`planner_svc.planners.exact.best_first`) for rotations inside
    ``window``, the disk of ``radius`` around ``centre``, with ``outside`` still.

    Such a search is decided by the cells within two of the window (rotations look no
    further), how the still part's components meet the window (cut tests), the budget,
    and what the caller's ``tag`` adds (its goal near the window being fixed, or decided by
    the cells there). Outcomes are kept in ``memo`` under that key and not searched
    again: failures unless ``exact()`` says the search looked beyond the key, paths if
    ``keep_found``. ``cap``: see :func:`planner_svc.planners.exact.best_first` (a search it
    stops is a failure for the caller to keep or not). Runs tried the same windows again
    after every success elsewhere, and on scrambled blobs of 1000 modules failed
    searches, most of them repeats, took three quarters of the time."""
    components = _still_components(window, outside)
    key = None
    if memo is not None:
        near = frozenset(c for c in disk(centre, radius + 2) if c in occ)
        meets = frozenset(Counter(frozenset(port) for port in components[1] if port).items())
        key = (centre, radius, budget, near, meets, *tag)
        if key in memo:
            kept = memo[key]
            return None if kept is None else list(kept)
    found, _ = best_first(frozenset(occ & window),
                          window_moves(window, outside, fixed, obstacles, components),
                          is_goal, priority, budget, cap)
    path = None if found is None else [(m, rule) for _, m, rule in found]
    if key is not None and (exact() if path is None else keep_found):
        memo[key] = None if path is None else list(path)
    return path

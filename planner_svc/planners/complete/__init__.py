"""``complete``: a heuristic planner for fleets of any size that aims to always finish.

The package, by part: :mod:`.phases` runs the phases below in turn and keeps the
plans that finish; :mod:`.walks` holds phases 0 and 1 (front and assigned walks);
:mod:`.relays` the relay heuristic; :mod:`.digging` its last resort (holes dug open
and refilled); :mod:`.smoothing` the smoothed shapes; :mod:`.steps` turns rotations
into the plan's moves. What follows is the whole planner, as a user meets it.

It finishes on every instance of the benchmark's four families (convex, sparse, Eden
and scrambled, up to 1000 modules) and on small fleets (the exact search takes over).
Large rough blobs (Eden, 1000 modules) take a minute or so and long plans, through the last
resort below, and not all finish: where the relays wall voids into lakes, opening them
can leave tens of voids. Where it does not finish it says "stuck" and never claims
unreachability. What the choices below gave when they were measured: docs/planner.md,
*Measured for what was kept*.

Modules are interchangeable, so only electrons (modules off the goal) need to move,
each to some void (empty goal cell).

Phase 0 (:class:`FrontWalk`), on compact goals (:func:`compact`), fills the goal row by
row outward from the cells already in place, each void by a lone walk (A* over the
surface) of a peelable electron, chosen by walk length and the lower bound's own
minimum-cost assignment; the row order keeps every void enterable and every free cell
passable. It solves hex-convex shapes (:func:`planner_svc.planners.bounds.random_convex_problem`)
up to 1000 modules in a second or two, with plans about 1.1-1.5x the bound. When it
finishes on a large fleet its plan is kept; otherwise the phases below start over.

Phase 1 (:class:`AssignWalk`) pairs electrons with voids by the lower bound's own
minimum-cost assignment and walks them alone (A* over the surface), shortest pairs
first, an electron going to the nearest void it reaches when its own is out of reach.
On sparse shapes (:func:`planner_svc.planners.bounds.random_sparse_problem`) it finishes on its
own. When it does not, the relay heuristic below runs from the start (it does better
on compact shapes) and, on fleets of :data:`SMOOTH_LIMIT` modules or fewer or when that
is stuck, also from where phase 1 stopped. Fleets of :data:`COMPARE_LIMIT` modules or
fewer run every phase. Candidates are compared as they will be played: shortened by
:mod:`planner_svc.planners.shorten` (detours dropped).

Before the relays, fleets of more than :data:`SMOOTH_LIMIT` modules whose assignment
bound is at most :data:`DESCENT_REACH` moves per electron (a local rearrangement, as the
scrambled blobs: 2-3) *descend the bound* (:mod:`planner_svc.planners.descent`): moves
that each lower the assignment bound by one, none sealing a void or freezing an
electron, short window searches where no move does, and wider ones that fill the last
few voids; the relays go on from where it stops. When they reach the goal that plan is
kept (mostly far shorter than the relays' from the start). If not, a few digs from where
it stopped come next (holes dug open and refilled), kept when the plan is at most
:data:`DUG_EARLY` times the bound; otherwise everything below runs from the start. Where
the relays are stuck too, digging on from where the descent stopped is kept when it is
at most :data:`DUG_KEEP` times the bound; otherwise it is one more try of the last
resort.

Under Table 4-3 a lone walker cannot cross a
notch of the surface (a free cell with four occupied neighbours: no rotation pivots
across its mouth), so on a rough structure each module reaches only a short stretch
of the surface. Material still flows by *relays*:

1. every movable module (not the fixed one, not an articulation point -- a local test
   that its occupied neighbours form one arc decides most cases, a breadth-first
   search the rest -- and with a legal rotation) gets its reach: a breadth-first search
   over the cells it reaches by legal rotations (:mod:`planner_svc.planners.rules`) with the
   rest still; with it lifted out the rest stays connected, so every step of its walk
   keeps the structure connected as it stays latched to a substrate;
2. Dijkstra over modules, backwards from the voids, finds the cheapest chain
   electron -> settled module -> ... -> void: a settled module walks to a void, the
   module behind it walks into the cell it left, and so on back to an electron. The
   cost is the walks' length, plus a large penalty for a fill that makes a nearby void
   unenterable (no pocket is sealed while another choice exists), minus a bonus for
   enclosed and deep voids (they only get harder to enter);
3. the chain's walks are made from the void end, each re-searched on the current
   structure;
4. when no chain exists, a void with an electron at most four cells away is filled by
   a best-first search in a window around it (:func:`local_exchange`): the electron is
   often walled in, or the void behind a notch, and settled modules stepping aside and
   back let the two trade places (Eden blobs of 10 modules: mean 1.41x the bound
   instead of 1.81x; scrambled blobs of 100: at most 2.1x instead of 17.8x);
5. on fleets of more than :data:`SMOOTH_LIMIT` modules, electrons far from every void
   *advance* (:meth:`Heuristic._advance_step`): one walks alone to the cell outside
   the goal nearest the voids along the surface (:func:`surface_field`), or a window
   search (:func:`local_advance`) lets settled modules step aside so electrons pass a
   notch. Parked electrons pave the rough surface for the next ones, until relays and
   exchanges take over (a scrambled blob of 1000 modules: solved, 689 moves in about
   6 s, where the heuristic stopped 4 voids short; Eden blobs of 1000: 19 voids left
   instead of 48). On smaller fleets the smoothed shapes below do better;
6. failing that, a small best-first search in a window around a blocked void (or
   trapped electron) may move settled modules out and back (:func:`local_repair`),
   pushing the vacancy out to the surface.

When the cheapest chain cannot be walked (e.g. it would repeat a configuration) the
next cheapest is tried (:data:`RELAY_RETRIES`).

If the heuristic is stuck it retries on the reverse problem (goal to initial, played
backwards: every rotation is undone about the same vertex, sweeping the same cells).
If that is stuck too, the relay heuristic runs once more as a last resort with *hole
digging* (:meth:`Heuristic._hole_step`): a hole (voids no movable electron reaches,
e.g. enclosed by a frozen interior) or a walled-in electron is dug out by a peel planned
on the structure with the hole filled -- movable modules (at most three neighbours, not
cut vertices, also in the real structure) inside a hexagonal ball that reaches from
beyond the nearest open surface to the hole walk one by one to parking cells outside
the goal, until every hole cell has been peeled; when the crater's walls end flat (a flat
face rotates only at its ends), the movable module nearest to the hole is peeled
instead, so a face is eaten from its end inwards -- then played for real: the crater's
peels forward, then the whole peel backwards (every move is reversible), with an
electron (or a waiting crater module, leaving a surface void) taking each hole cell.
Each walk is re-searched on the current structure; a fill that fails is rolled back.
A hole's first dig takes the first peel found; when the same cells are dug again, wider
and deeper craters and other parkings are tried in turn (:data:`HOLE_DIGS`): holes a
few cells deep in the bulk need them, and trying them first makes the plans longer. A
walled-in electron is dug out once per cell per set of voids (freed electrons that fill
nothing are walled in again elsewhere, and digs went round in circles). A hole of more
than :data:`HOLE_MAX` voids (a *lake*, walled in by the relays) is not refilled but
opened for good (:meth:`Heuristic._open_lake`): a crater to the lake's shore module with
the thinnest wall, its modules parked outside the goal; the relays then fill the crater's
cells last while lake voids remain (filled first, they seal the lake again), and another
lake is opened only once fewer voids are left than when the last one was. When no dig
works, a walled-in electron is freed by a detour (:meth:`Heuristic._clear_wedge`): the
relays play towards the goal with a 120-degree :func:`wedge` of the structure at the
electron traded for a coat of parking cells, until the electron has left its cell, and
then refill the wedge apex first. Under a flat face only a row's ends peel, so only a
corner reaches a module in the bulk; the relays carry the wedge's modules past the
notches of its rough far side, where lone walks to parking cells stop.
These plans are long (Eden blobs of 100 modules: up to 8x the bound, 4.7x once
:mod:`planner_svc.planners.shorten` has dropped their detours) but reach the goal.
The same is also tried between *smoothed* shapes (:func:`smoothed_plan`): the notches
of the start and of the goal are filled first by local repairs (:func:`smooth`; the
goal's smoothing is played backwards at the end), so fewer notches stop the walkers, the
relays go further and less is dug; the shorter plan is kept (Eden blobs of 100 modules:
3.8x the bound on two of three seeds; on fleets over :data:`SMOOTH_LIMIT` modules, with
advances and up to :data:`HOLE_CALLS_LARGE` digs). On those fleets, unless voids are
walled in (below), the relays also run again, digging where they stop, with the voids
next to a *pinned* electron waiting while it is there (:meth:`Heuristic._pinned`: with
the goal complete around it, it could not rotate; relays that stopped had often walled
such electrons into cracks of the goal), and the shortest of the three plans is kept. On
those larger fleets, relays that stop with more than :data:`FEW_VOIDS` voids left have
walled voids in: the relays from where phase 1 stopped and on the reverse problem are
skipped, the smoothed shapes go first and plain digging runs only when they fail. If
that fails too, small fleets (``exact_limit`` modules or fewer) fall back to
:mod:`planner_svc.planners.exact` from the current configuration, which also proves
unreachability (moves are reversible, so unreachable from there is unreachable from the
start); larger fleets report that the heuristic is stuck, without claiming
unreachability.

The plan kept is shortened once more and re-planned in small windows
(:func:`planner_svc.planners.shorten.replan_windows`: stretches of moves inside a disk of radius
2-4 replaced by the fewest rotations there, every other round on the plan played
backwards; scrambled blobs of 1000 modules: 19-32% fewer moves, for up to 13 s). Last,
on fleets of :data:`FEWEST_LIMIT` modules or fewer, the exact search looks for a plan
with fewer moves than that
(:func:`planner_svc.planners.exact.fewer_moves`, at most :data:`FEWEST_BUDGET` configurations,
stopping as soon as none can be shorter): the benchmark's Eden and scrambled instances
of 10 modules get the fewest, and on thesis-12 it proves that the 18 moves the windows
leave (the heuristics plan 19) are the fewest.
"""

from .phases import plan_complete

__all__ = ["plan_complete"]

"""The four rotation programs of Appendix A (spec §7, codes 21..24), as data.

One table for everything that runs or reasons about a rotation: the control board
executes it on its relays and solenoids, the comm board's LED mirrors (codes 56..59)
replay it on the LEDs, and the physics tests turn it into actuator timelines.

A step is ``(op, k)`` acting on joint/side ``i + k`` (folded into 1..6), ``("wait", "t1")``
for ``DelayXts(t1)``, or an ``*_all`` op:

=============  ======================  ================================
op             control board           comm board LED mirror
=============  ======================  ================================
``open``       ``JxOpen(i+k)``         ``JointOn(i+k)``
``close_all``  ``JxCloseAll()``        ``JointOffAll()``
``pos``        ``SxP(i+k)``            ``SideOnP(i+k)``
``neg``        ``SxN(i+k)``            ``SideOnN(i+k)``
``off_all``    ``SxOffAll()``          ``SideOffAllP(); SideOffAllN()``
=============  ======================  ================================
"""

from __future__ import annotations

from typing import Callable, Iterator, NamedTuple

from .lattice import Direction, Joint, MoveRule

Step = tuple  # ("open", k) | ("wait", "t1") | ("close_all",) ...

MCW: tuple[Step, ...] = (("open", 0), ("open", 1), ("wait", "t1"), ("neg", 0), ("neg", -1),
                         ("wait", "t2"), ("close_all",), ("wait", "t3"), ("off_all",))
MCCW: tuple[Step, ...] = (("open", 1), ("wait", "t1"), ("neg", 0), ("neg", -1), ("wait", "t2"),
                          ("open", 0), ("wait", "t3"), ("close_all",), ("off_all",))
SCW: tuple[Step, ...] = (("open", -1), ("wait", "t1"), ("neg", -3), ("pos", -2), ("wait", "t2"),
                         ("open", -2), ("wait", "t3"), ("close_all",), ("off_all",))
#: Appendix A as it ran: S(i-5) negative although its comment says positive (spec §12).
SCCW_AS_RAN: tuple[Step, ...] = (("open", -3), ("open", -4), ("wait", "t1"), ("neg", -4),
                                 ("neg", -5), ("wait", "t2"), ("close_all",), ("wait", "t3"),
                                 ("off_all",))
#: The comment's intent (profile v2): S(i-5) positive.
SCCW: tuple[Step, ...] = tuple(("pos", -5) if s == ("neg", -5) else s for s in SCCW_AS_RAN)

_BY_NAME = {"MCW": MCW, "MCCW": MCCW, "SCW": SCW, "SCCW": SCCW}
#: LED mirror (comm board) -> the rotation it mirrors.
MIRRORS = {"LMCW": "MCW", "LMCCW": "MCCW", "LSCW": "SCW", "LSCCW": "SCCW"}


def steps(name: str, *, sccw_both_negative: bool = False) -> tuple[Step, ...]:
    """The steps of ``MCW``/``MCCW``/``SCW``/``SCCW`` (or their LED mirrors ``L…``)."""
    name = MIRRORS.get(name, name)
    if name == "SCCW" and sccw_both_negative:
        return SCCW_AS_RAN
    return _BY_NAME[name]


def perform(name: str, i: int, t1: int, t2: int, t3: int, *,
            actions: dict[str, Callable[..., None]], sccw_both_negative: bool = False
            ) -> Iterator[int]:
    """Apply a rotation's steps through ``actions`` (op -> function; ``open``/``pos``/``neg``
    receive ``i + k``, which the board folds into 1..6) and yield the ticks of each wait."""
    waits = {"t1": t1, "t2": t2, "t3": t3}
    for op, *arg in steps(name, sccw_both_negative=sccw_both_negative):
        if op == "wait":
            yield waits[arg[0]]
        elif arg:
            actions[op](i + arg[0])
        else:
            actions[op]()


def two_substrates(dirs: int, i1: int, i2: int) -> list[tuple[str, int]]:
    """``STwo``'s two substrate programs (SCW if its bit of ``dirs`` is set, else SCCW, about
    body joint i), for :func:`perform_together`."""
    return [("SCW" if dirs >> k & 1 else "SCCW", i) for k, i in enumerate((i1, i2))]


def perform_together(rotations: list[tuple[str, int]], t1: int, t2: int, t3: int, *,
                     actions: dict[str, Callable[..., None]], sccw_both_negative: bool = False
                     ) -> Iterator[int]:
    """Several rotations at once on one board (a substrate two movers turn about in the same
    Walter round): every program has its waits t1, t2, t3 in the same places, so each phase
    applies the steps of every program in turn, then waits once."""
    phases: list[list[list[Step]]] = []
    for name, _ in rotations:
        segs: list[list[Step]] = [[]]
        for step in steps(name, sccw_both_negative=sccw_both_negative):
            if step[0] == "wait":
                segs.append([])
            else:
                segs[-1].append(step)
        phases.append(segs)
    waits = (t1, t2, t3)
    for k in range(len(waits) + 1):
        for (_, i), segs in zip(rotations, phases):
            for op, *arg in segs[k]:
                if arg:
                    actions[op](i + arg[0])
                else:
                    actions[op]()
        if k < len(waits):
            yield waits[k]


class RotationArgs(NamedTuple):
    """Arguments ``mi`` (mobile) and ``si`` (substrate) of MCW/SCW, MCCW/SCCW and of
    the combined codes CW (67) and CCW (68)."""

    mi: int
    si: int


def rotation_arguments(rule: MoveRule, mobile_orientation: int,
                       substrate_orientation: int) -> RotationArgs:
    """The (mi, si) that make the firmware perform the Table 4-3 move ``rule``.

    Both are the global pivot joint j written in each module's own body frame:
    ``mi = j - o_mobile``, ``si = j - o_substrate`` (folded into 1..6). Then
    MCW/MCCW(mi) energise the mobile's body sides mi-1, mi (global j-1, j: both sides at
    the pivot); SCW(si) repels with body side si-3 = global j+3 (facing the mobile across
    its side j) and attracts with si-2 = global j+4; SCCW(si) repels with si-4 = global
    j+2 (facing the mobile across its side j-1) and attracts with si-5 = global j+1.
    """
    j = int(rule.joint)
    return RotationArgs(int(Joint.of(j - mobile_orientation)),
                        int(Joint.of(j - substrate_orientation)))


def orientation_after(orientation: int, direction: Direction | str) -> int:
    """Orientation after a move. Sides are numbered clockwise, so turning the body
    120 degrees clockwise carries body side s from global side g to g + 2."""
    step = 2 if Direction(direction) is Direction.CW else -2
    return (orientation + step) % 6

"""A synthetic run on a private bus: a known set of frames and records at known sim times.

Used by the tests and the benchmark (and handy to try ``hexbench replay`` without the
virtual fleet). It talks only through the bus (principle 1) and keeps its own list of
everything it published, so a recording can be checked against an independent count.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Any, Callable

from bus.clock import VirtualClock
from bus.codec import (Link, encode_ack, encode_command, encode_debug_msg, encode_msg1,
                       encode_relay, parse)
from bus.envelope import Envelope
from bus.lattice import MOVE_RULES, Cell, rotate_about_vertex
from bus.messages import Actuators, Energy, PlannerProgress, PlannerState, Pose, Record, RunMeta, WorldEvent
from bus.session import SessionOptions
from bus.transport import Bus

MOVE_NS = 220_000_000  # one 120-degree rotation (spec §1)
STEP_NS = 500_000_000
BAUD = 9600


def wire_ns(n_bytes: int, baud: int = BAUD) -> int:
    """Time for ``n_bytes`` on a UART: 10 bits a byte."""
    return n_bytes * 10 * 1_000_000_000 // baud


@dataclass
class Published:
    """What a synthetic run put on the bus, counted by the run itself."""

    frames: list[Envelope] = field(default_factory=list)
    records: list[tuple[str, Record | dict[str, Any]]] = field(default_factory=list)  # (topic, value)
    malformed: list[tuple[str, bytes]] = field(default_factory=list)  # (topic, payload)
    final_poses: dict[str, Pose] = field(default_factory=dict)
    end_ns: int = 0

    def frames_by_link(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for e in self.frames:
            out[e.link] = out.get(e.link, 0) + 1
        return out


class SyntheticRun:
    """Schedules a deterministic run (same arguments -> same frames at the same sim times)."""

    def __init__(self, bus: Bus, *, modules: int = 4, moves: int = 3, seed: int = 1,
                 filler_frames: int = 0, malformed: bool = True) -> None:
        self.bus = bus
        self.rng = random.Random(seed)
        self.seed = seed
        self.filler = filler_frames  # extra side frames per step (benchmark density)
        self.n_moves = moves
        self.with_malformed = malformed
        self.cells: dict[str, Cell] = {f"m{i + 1}": Cell(i, 0) for i in range(modules)}
        self.orientation: dict[str, int] = {m: 0 for m in self.cells}
        self.published = Published()
        self.energy_j = 0.0

    # -- publishing helpers (each keeps its own count) ------------------------------------------
    def _frame(self, link: Link, raw: bytes, src: str, dst: str, **extra: Any) -> None:
        env = self.bus.publish_frame(parse(link, raw), src=src, dst=dst,
                                     first_byte_ns=max(0, self.bus.clock.now_ns() - wire_ns(len(raw))),
                                     **extra)
        self.published.frames.append(env)

    def _record(self, key: str, rec: Record) -> None:
        self.bus.put(key, rec.to_json())
        self.published.records.append((self.bus.keys.relative(key), rec))

    def _at(self, t_ns: int, fn: Callable[..., None], *args: Any) -> None:
        self.bus.clock.call_at(t_ns, fn, *args)

    # -- the run ---------------------------------------------------------------------------------
    def schedule(self) -> None:
        """Put the whole run on the clock; ``clock.run()`` plays it."""
        self._at(0, self._start)
        for step in range(self.n_moves):
            self._at((step + 1) * STEP_NS, self._step, step)
        self.published.end_ns = (self.n_moves + 1) * STEP_NS
        self._at(self.published.end_ns, self._finish)

    def _start(self) -> None:
        k = self.bus.keys
        self._record(k.meta, RunMeta(scenario="synthetic", profile="v2", seed=self.seed,
                                     planner="scripted", clock="virtual", argv=["synthetic"],
                                     versions={}, fleet=k.fleet))
        for m in self.cells:
            self._pose(m)
            self._actuators(m, joints=[False] * 6, magnets=[0] * 6)
        self._frame(Link.CENTRE, b"\n\r\n\rCOMM. BOARD READY\n\r", "m1.comm", "pc", channel=0)

    def _pose(self, m: str) -> None:
        c = self.cells[m]
        pose = Pose(module=m, id=int(m[1:]), x=c.x, y=c.y, orientation=self.orientation[m],
                    sim_time_ns=self.bus.clock.now_ns(), fixed=(m == "m1"))
        self._record(self.bus.keys.pose(m), pose)
        self.published.final_poses[m] = pose

    def _actuators(self, m: str, *, joints: list[bool], magnets: list[int]) -> None:
        self._record(self.bus.keys.actuators(m), Actuators(
            module=m, sim_time_ns=self.bus.clock.now_ns(), joints_open=joints, magnets=magnets,
            led_pos=[v > 0 for v in magnets], led_neg=[v < 0 for v in magnets],
            led_joint=joints, ir_channel=0))

    def _choose_move(self) -> tuple[str, Any] | None:
        occupied = set(self.cells.values())
        for m in sorted(self.cells, reverse=True):  # the tail first; m1 is fixed
            if m == "m1":
                continue
            rules = list(MOVE_RULES)
            self.rng.shuffle(rules)
            for r in rules:
                sub, empty, goal = r.cells(self.cells[m])
                if sub in occupied and goal not in occupied and not (set(empty) & occupied):
                    return m, r
        return None

    def _step(self, step: int) -> None:
        k = self.bus.keys
        choice = self._choose_move()
        self._record(k.planner("state"), self._planner_state(step))
        if choice is None:
            return
        m, rule = choice
        ident = int(m[1:])
        # PC command on the centre IR, relayed to the control board, echoed, acknowledged.
        code = 21 if rule.direction.value == "CW" else 22
        self._frame(Link.PC, encode_command(code, int(rule.joint), 8, 4, 9), "pc", "*", channel=0)
        self._at(self.bus.clock.now_ns() + 5_000_000, self._relay, m, code, int(rule.joint))
        self._at(self.bus.clock.now_ns() + 20_000_000, self._move, m, rule, ident)
        for n in range(self.filler):  # side traffic between neighbours (MSG1 with coordinates)
            self._at(self.bus.clock.now_ns() + 30_000_000 + n * 1_000_000, self._side_msg, n)

    def _relay(self, m: str, code: int, joint: int) -> None:
        self._frame(Link.UART0_DOWN, encode_relay(code, joint, 8, 4, 9), f"{m}.comm", f"{m}.ctrl")
        self._frame(Link.UART0_UP, bytes([code]), f"{m}.ctrl", f"{m}.comm")
        self._frame(Link.CENTRE, encode_ack(code), f"{m}.comm", "pc", channel=0)
        self._frame(Link.DEBUG, encode_debug_msg(bytes([code, joint, 8, 4, 9])), f"{m}.ctrl", "pc")

    def _side_msg(self, n: int) -> None:
        mods = sorted(self.cells)
        m = mods[n % len(mods)]
        c = self.cells[m]
        side = n % 6 + 1
        self._frame(Link.SIDE, encode_msg1(c.x, c.y, side), f"{m}.comm", "*", channel=side)

    def _move(self, m: str, rule: Any, ident: int) -> None:
        k = self.bus.keys
        cell = self.cells[m]
        sub, _, goal = rule.cells(cell)
        sub_name = next(n for n, c in self.cells.items() if c == sub)
        ccw = rule.direction.value == "CCW"
        pivot = cell.vertex(int(rule.joint))
        before = self.orientation[m]
        after = (before + (-2 if ccw else 2)) % 6  # sides count clockwise: CCW lowers Yref
        joints = [j != int(rule.joint) - 1 for j in range(6)]  # only the pivot joint closed
        self._actuators(m, joints=joints, magnets=[-1 if s in (int(rule.joint) - 2, int(rule.joint) - 1) else 0
                                                   for s in range(6)])
        self._record(k.world_event, WorldEvent(
            kind="move-started", sim_time_ns=self.bus.clock.now_ns(), module=m,
            data={"from": [cell.x, cell.y], "to": [goal.x, goal.y], "pivot": list(pivot),
                  "direction": rule.direction.value, "joint": int(rule.joint), "substrate": sub_name,
                  "duration_ns": MOVE_NS, "orientation_before": before, "orientation_after": after}))
        end = rotate_about_vertex(cell.centre(), pivot, 120 if ccw else -120)
        assert abs(end[0] - goal.centre()[0]) < 1e-9, "Table 4-3 and the lattice disagree"
        self._at(self.bus.clock.now_ns() + MOVE_NS, self._moved, m, goal, after, ident)
        if self.with_malformed and ident % 2 == 0:
            self._frame(Link.SIDE, b"\x07\x07\x07", f"{m}.comm", "*", channel=3)  # noise is a frame
            self.bus.event(f"{m}.comm", "overrun", detail="synthetic")
            self.published.records.append((f"event/{m}.comm", {"kind": "overrun"}))

    def _moved(self, m: str, goal: Cell, after: int, ident: int) -> None:
        k = self.bus.keys
        self.cells[m] = goal
        self.orientation[m] = after
        self._record(k.world_event, WorldEvent(kind="move-completed", sim_time_ns=self.bus.clock.now_ns(),
                                               module=m, data={"to": [goal.x, goal.y]}))
        self._pose(m)
        self._actuators(m, joints=[False] * 6, magnets=[0] * 6)
        self.energy_j += 22.7
        self._record(k.world_energy, Energy(sim_time_ns=self.bus.clock.now_ns(), module=m,
                                            move_j=22.7, run_j=self.energy_j,
                                            by_actuator={"magnets": 19.2, "solenoids": 2.0, "logic": 1.5}))

    def _planner_state(self, step: int) -> PlannerState:
        occ = sorted(self.cells.values())
        goal = [Cell(c.x, c.y + 1) for c in occ]
        return PlannerState(sim_time_ns=self.bus.clock.now_ns(), step=step, planner="scripted",
                            occupied=[[c.x, c.y] for c in occ], goal=[[c.x, c.y] for c in goal],
                            electrons=[[occ[-1].x, occ[-1].y]], voids=[[goal[0].x, goal[0].y]],
                            potential_voids=[[goal[-1].x, goal[-1].y]],
                            pairs=[[[occ[-1].x, occ[-1].y], [goal[0].x, goal[0].y]]],
                            value_cells=[[c.x, c.y] for c in occ + goal],
                            values=[float(i) for i in range(len(occ) + len(goal))])

    def _finish(self) -> None:
        k = self.bus.keys
        self._record(k.world_event, WorldEvent(kind="fault", sim_time_ns=self.bus.clock.now_ns(),
                                               module="m2", reason="synthetic fault: both relays"))
        self._record(k.planner("progress"), PlannerProgress(
            sim_time_ns=self.bus.clock.now_ns(), step=self.n_moves, moves=self.n_moves,
            goal_filled=0, goal_total=len(self.cells), message="done", done=True))
        if self.with_malformed:  # errors are data: the recorder must keep these too
            for payload in (b"\xff not json", b'{"kind":"ack"}'):
                key = k.frame("centre", "bogus") if payload.startswith(b"{") else k.event("bogus")
                self.bus.put(key, payload)
                self.published.malformed.append((k.relative(key), payload))


def run_synthetic(fleet: str = "synthetic", *, attach: Callable[[Bus], Any] | None = None,
                  timeout_s: float = 120.0, **kwargs: Any) -> Published:
    """Run a synthetic run to its end on a private bus; ``attach(bus)`` adds e.g. a recorder
    before anything is published."""
    bus = Bus(VirtualClock(), fleet, options=SessionOptions(isolated=True))
    try:
        if attach is not None:
            attach(bus)
        run = SyntheticRun(bus, **kwargs)
        run.schedule()
        bus.clock.run(timeout_s=timeout_s)
        return run.published
    finally:
        bus.close()

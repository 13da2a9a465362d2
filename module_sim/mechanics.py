"""The world's mechanics on the bus: actuator records in, moves, faults and energy out.

Every virtual module publishes its actuator port bits on ``world/actuators/<m>``.
:class:`Mechanics` feeds them (through any injected :mod:`bus.faults`) to the pure
:class:`module_sim.physics.MotionJudge` and :class:`module_sim.energy.EnergyMeter`,
wakes itself on the clock when a break-away, carry or arrival falls due, and publishes
what happened on ``world/event`` (``move-started``, ``move-completed``,
``move-refused``, ``fault``: always with the reason) and ``world/energy``. The
:class:`module_sim.world.World` owns it and moves its bodies when a move completes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Callable, Iterable

from bus.faults import ActuatorFault, apply_all
from bus.lattice import Cell
from bus.messages import Actuators, Energy, WorldEvent
from bus.transport import Bus

from .energy import EnergyBreakdown, EnergyMeter
from .physics import (Fault, ModuleSpec, MotionJudge, MoveCompleted, MoveRefused, MoveStarted,
                      Outcome, PhysicsParams, orientation_after)


@dataclass
class Body:
    """A module's body in the world: where it is, and whether it is the fixed one."""

    module: str
    id: int
    cell: Cell
    orientation: int
    kind: str = "virtual"
    fixed: bool = False


#: how a virtual module's actuator record ends (bus.messages.Actuators, as VirtualModule writes it)
_VIRTUAL_END = b'"origin":"virtual","type":"actuators"}'
#: the joints and magnets of each coils' JSON seen (a fleet has a few dozen)
_COIL_BITS: dict[bytes, tuple[list[bool], list[int]]] = {}


class Mechanics:
    """Physics and energy of a fleet, driven by the actuator records on the bus."""

    def __init__(self, bus: Bus, bodies: dict[str, Body], obstacles: set[Cell],
                 on_moved: Callable[[MoveCompleted], None], *,
                 faults: list[ActuatorFault] | None = None,
                 params: PhysicsParams = PhysicsParams(),
                 own: Iterable[str] | None = None, lagged: bool = False) -> None:
        """``own``: the modules whose outcomes this world publishes (a shard's; default all).
        ``lagged`` (a shard on a lockstep clock): actuator records from every shard are
        judged at each window's end, in time order, once all of the window's are here; so
        every shard's replica of the physics reaches the same outcomes, each publishing its
        own modules'. Outcomes are then published up to one window late (docs/bus.md)."""
        self.bus = bus
        self.params = params
        self.judge = MotionJudge([ModuleSpec(b.module, b.cell, b.orientation, b.fixed)
                                  for b in bodies.values()], obstacles, params)
        self.modules = frozenset(bodies)
        self.own = self.modules if own is None else frozenset(own)
        self.lagged = lagged
        self._queue: list[tuple[int, str, list[bool], list[int]]] = []  # lagged: records to judge
        if lagged:
            bus.clock.at_boundary.append(self._at_boundary)  # type: ignore[attr-defined]
        self.meter = EnergyMeter()
        self.on_moved = on_moved
        self.faults: dict[str, list[ActuatorFault]] = {}
        self.outcomes: list[Outcome] = []
        self._commanded: dict[str, tuple[list[bool], list[int]]] = {}
        self._coils: dict[str, bytes] = {}  # key -> the coils' JSON of its last virtual record
        #: real modules whose board's reports differed from their twin's: moved by the board's
        self.board_bits: set[str] = set()
        self._board_said: dict[str, Actuators] = {}  # each board's latest report
        self._wake_at: int | None = None
        for f in faults or ():
            self.inject(f)
        bus.subscribe(bus.keys.actuators_all, self._on_actuators)
        bus.subscribe(bus.keys.world_inject, self._on_inject)
        bus.subscribe_json(f"{bus.keys.root}/event/*", self._on_event)

    # -- faults -------------------------------------------------------------------------------
    def inject(self, fault: ActuatorFault) -> None:
        """From now on the actuator behaves as ``fault`` says (re-applied to its current state)."""
        if fault.module not in self.modules:
            raise KeyError(f"fault {fault}: no module {fault.module!r} in this world")
        self.faults.setdefault(fault.module, []).append(fault)
        if fault.module in self.own:
            self.bus.put(self.bus.keys.world_event, WorldEvent(
                "fault-injected", self.bus.clock.now_ns(), fault.module, "injected",
                {"fault": str(fault), "detail": fault.describe()}).to_json())
        if fault.module in self._commanded:
            self._feed(fault.module, self.bus.clock.now_ns(), *self._commanded[fault.module])

    def _on_inject(self, key: str, payload: bytes) -> None:
        """``{"fault": "m3.S2-:off"}``; anything else raises (a ``bad-sample`` event when the
        sample came from another process)."""
        d = json.loads(payload)
        spec = d.get("fault") if isinstance(d, dict) else None
        if not isinstance(spec, str):
            raise ValueError(f"an injection is {{\"fault\": \"<spec>\"}}, not {payload[:80]!r}")
        try:
            self.inject(ActuatorFault.parse(spec))
        except KeyError as exc:  # a module this world does not hold
            raise ValueError(str(exc)) from None

    # -- actuators in --------------------------------------------------------------------------
    def _on_actuators(self, key: str, payload: bytes) -> None:
        # Most records change LEDs or the multiplexer only: a virtual module's record whose
        # coils read as in its last one is passed over before it is decoded.
        i = payload.find(b'"joints_open":')
        coils = payload[i:payload.find(b',"led_pos"', i)] if i > 0 else None
        virtual = coils is not None and payload.endswith(_VIRTUAL_END)
        if virtual and not self.lagged and self._coils.get(key) == coils:
            return
        if virtual and payload.startswith(b'{"module":"'):
            self._on_virtual(key, payload, coils)
            return
        a = Actuators.from_json(payload)
        if a.module not in self.modules:
            return  # a module the world does not hold (another fleet's stand-in, say)
        # A real module's body follows its twin's bits, on time, while its board's actuator
        # reports agree with them (the twin check on the debug link); once they differ, the
        # board's own bits, as they arrive (module_sim.twin, docs/hil.md).
        if a.origin == "serial":
            self._board_said[a.module] = a
        if a.origin != "virtual" and (a.origin == "serial") != (a.module in self.board_bits):
            return
        if virtual:
            self._coils[key] = coils
        self._command(a.module, a.sim_time_ns, a.joints_open, a.magnets)

    def _on_virtual(self, key: str, payload: bytes, coils: bytes) -> None:
        """A virtual module's record as VirtualModule.publish_actuators writes it: the module,
        the time and the coils read off the bytes (the coils' few states decoded once each)."""
        end = payload.index(b'"', 11)
        module = payload[11:end].decode()
        if module not in self.modules:
            return  # a module the world does not hold (another fleet's stand-in, say)
        t = int(payload[end + 16:payload.index(b",", end + 16)])
        self._coils[key] = coils
        bits = _COIL_BITS.get(coils)
        if bits is None:
            d = json.loads(b"{" + coils + b"}")
            bits = _COIL_BITS[coils] = (d["joints_open"], d["magnets"])
        self._command(module, t, *bits)

    def _command(self, module: str, t: int, joints: list[bool], magnets: list[int]) -> None:
        """The bits ``module``'s body follows from ``t``: judged now, or (lagged) at the
        window's boundary."""
        bits = (list(joints), list(magnets))
        if not self.lagged and self._commanded.get(module) == bits:
            return  # the LEDs or the multiplexer changed: nothing a body or the meter follows
        self._commanded[module] = bits
        if self.lagged:
            self._queue.append((t, module, list(joints), list(magnets)))
            return
        self._feed(module, t, list(joints), list(magnets))

    def _at_boundary(self, t_ns: int) -> None:
        """Lagged: judge the window's records from everywhere in time order, and what falls
        due before the boundary."""
        queue, self._queue = sorted(self._queue, key=lambda r: (r[0], r[1])), []
        for t, module, joints, magnets in queue:
            self._feed(module, t, joints, magnets)
        self._handle(self.judge.advance(max(t_ns - 1, self.judge.now_ns)))

    def at_rest(self) -> bool:
        """No body moves and no module tries to: an actuator change that makes no magnet pair
        and no relay fight starts nothing, whenever it is judged (the fleet core lets such
        changes wait for its window's end)."""
        return not self.lagged and self.judge.at_rest()

    def bits(self, module: str) -> tuple[list[bool], list[int]] | None:
        """The joints and magnets the body of ``module`` follows now (before faults)."""
        return self._commanded.get(module)

    def _on_event(self, key: str, d: dict) -> None:
        """A real board's actuator report differed from its twin's: from now on the board's
        bits move its body (the report that differed came before the check said so)."""
        module = d.get("src")
        if d.get("kind") != "twin-diverged" or d.get("link") != "debug" or module not in self.modules:
            return
        self.board_bits.add(module)
        a = self._board_said.get(module)
        if a is not None:
            self._commanded[module] = (list(a.joints_open), list(a.magnets))
            self._feed(module, a.sim_time_ns, list(a.joints_open), list(a.magnets))

    def _feed(self, module: str, t_ns: int, joints: list[bool], magnets: list[int]) -> None:
        t = max(t_ns, self.judge.now_ns)  # wall clock: a record may lag the judge a little
        joints, magnets = apply_all(self.faults.get(module, ()), joints, magnets)
        self.meter.on_actuators(module, t, joints, magnets)
        self._handle(self.judge.on_actuators(module, t, joints, magnets))

    def _wake(self) -> None:
        self._wake_at = None
        now = self.bus.clock.due_ns()
        self._handle(self.judge.advance(max(now, self.judge.now_ns)))

    def _reschedule(self) -> None:
        if self.lagged:
            return  # deadlines are judged at the boundaries
        due = self.judge.next_deadline()
        if due is not None and (self._wake_at is None or due < self._wake_at):
            self._wake_at = due
            self.bus.clock.call_at(due, self._wake)

    # -- outcomes out --------------------------------------------------------------------------
    def _handle(self, outcomes: list[Outcome]) -> None:
        for o in outcomes:
            self.outcomes.append(o)
            if o.module not in self.own:  # another shard's module: that shard says it
                if isinstance(o, MoveCompleted):
                    self.meter.record_move(o)
                    self.on_moved(o)
                continue
            if isinstance(o, MoveStarted):
                self._publish_started(o)
            elif isinstance(o, MoveCompleted):
                self._publish_completed(o)
            elif isinstance(o, (MoveRefused, Fault)):
                kind = "move-refused" if isinstance(o, MoveRefused) else "fault"
                self._event(kind, o.t_ns, o.module, o.reason.value,
                            {"detail": o.detail, **o.data})
        self._reschedule()

    def _event(self, kind: str, t_ns: int, module: str, reason: str, data: dict[str, Any]) -> None:
        ev = WorldEvent(kind, t_ns, module, reason, json.loads(json.dumps(data, default=str)))
        self.bus.put(self.bus.keys.world_event, ev.to_json())

    def _publish_started(self, o: MoveStarted) -> None:
        before = self.judge.orientation(o.module)
        pivot = o.from_cell.vertex(int(o.pivot_joint_global))
        self._event("move-started", o.t_ns, o.module, "", {
            "from": list(o.from_cell), "to": list(o.to_cell), "pivot": list(pivot),
            "direction": o.direction.value, "joint": int(o.pivot_joint_global),
            "substrate": o.substrate, "started_ns": o.started_ns,
            "duration_ns": self.params.rotation_ns, "orientation_before": before,
            "orientation_after": orientation_after(before, o.direction)})

    def _publish_completed(self, o: MoveCompleted) -> None:
        e = self.meter.record_move(o)
        self._event("move-completed", o.t_ns, o.module, "", {
            "from": list(o.from_cell), "to": list(o.to_cell), "direction": o.direction.value,
            "joint": int(o.pivot_joint_global), "substrate": o.substrate,
            "duration_ns": o.t_ns - o.started_ns, "orientation_before": o.orientation_before,
            "orientation_after": o.orientation_after, "energy_j": round(e.total_j, 6)})
        self.on_moved(o)
        run = self.run_energy()
        self.bus.put(self.bus.keys.world_energy, Energy(
            o.t_ns, o.module, e.total_j, run.total_j,
            {k: round(v, 6) for k, v in e.by_actuator().items()}).to_json())

    # -- queries ------------------------------------------------------------------------------
    def run_energy(self) -> EnergyBreakdown:
        """Energy of the run so far: all actuator on-time plus the logic of every move."""
        return self.meter.run_energy(max(self.bus.clock.now_ns(), self.judge.now_ns))

    def publish_run_energy(self) -> EnergyBreakdown:
        """Publish the run total (module None, move_j 0) and return it."""
        run = self.run_energy()
        self.bus.put(self.bus.keys.world_energy, Energy(
            self.bus.clock.now_ns(), None, 0.0, run.total_j,
            {k: round(v, 6) for k, v in run.by_actuator().items()}).to_json())
        return run

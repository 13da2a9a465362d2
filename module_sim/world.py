"""The world: ground truth of where modules are, their optical switches, and the IR medium.

Its :class:`module_sim.mechanics.Mechanics` turns actuator records into moves, refusals,
faults and energy (``world/event``, ``world/energy``). It publishes poses
(``world/pose/<module>``) and optical switches
(``world/switches/<module>``), and carries IR light: a burst on ``ir/tx/<src>`` is
forwarded on ``ir/rx/<dst>`` to every transceiver the light reaches —

* from the PC: the centre transceiver (0) of every module; from a module's centre
  transceiver: the PC's;
* the neighbour across body side s, on the transceiver of its facing side (Table 4-1,
  through both modules' orientations), for a side channel.

Two bursts overlapping in time on one receiver collide: both arrive garbled and a
``collision`` event says who collided and what the receiver got. A seeded bit error
rate flips bits for fault tests.
"""

from __future__ import annotations

import json
import random
from typing import Any

from bus.ir import Burst, cut_message, forwarded, garble_fixes
from bus.keys import PC, WORLD, module_endpoint
from bus.lattice import Cell, Side, body_to_global, global_to_body
from bus.messages import Pose, Switches, WorldEvent
from bus.scenario import Scenario
from bus.transport import Bus

from .air import Air
from .mechanics import Body, Mechanics
from .physics import MoveCompleted


class World:
    def __init__(self, bus: Bus, scenario: Scenario, *, own: set[str] | None = None,
                 pc: bool = True, physics: bool = True, slack_ns: int = 0) -> None:
        """The whole world, or a shard's part of it (:mod:`module_sim.shards`): ``own``
        names the modules whose receivers, poses, switches and moves it handles (default
        all), ``pc`` whether it carries light to the PC's receiver. Every part keeps every
        body's pose (light and moves need the whole lattice); a shard's physics is lagged
        (:class:`Mechanics`). ``slack_ns``: how late light may reach this part (two lockstep
        windows): the IR medium keeps bytes that long after they end, for light still to come."""
        self.bus = bus
        self.scenario = scenario
        self.bodies: dict[str, Body] = {}
        for m in scenario.modules:
            name = module_endpoint(m.id)
            self.bodies[name] = Body(name, m.id, m.cell, m.orientation, m.kind, m.cell == scenario.fixed)
        self._by_cell: dict[Cell, Body] = {b.cell: b for b in self.bodies.values()}
        self.own = set(self.bodies) if own is None else set(own)
        self.pc = pc
        self._whole = own is None and pc  # the one-process world: no filtering of receivers
        self.slack_ns = slack_ns
        self.obstacles = set(scenario.obstacles)
        self._rng = random.Random(scenario.seed)
        self.ber = scenario.bit_error_rate
        self._air: dict[tuple[str, int], Air] = {}  # receiver (dst, transceiver) -> bytes in flight
        self.collisions = 0
        self._switches_said: dict[str, list[bool]] = {}  # module -> the switches last published
        #: the module_sim.core.FleetCore that carries the light, if any (the Fleet sets it)
        self.core: Any = None
        bus.subscribe(bus.keys.ir_tx_all, self._on_ir)
        bus.subscribe(bus.keys.world_sync, lambda k, p: self.start())
        bus.subscribe(bus.keys.world_confirm, self._on_confirm)
        self.mechanics = Mechanics(bus, self.bodies, self.obstacles, self._moved,
                                   faults=list(scenario.faults), own=self.own,
                                   lagged=own is not None) if physics else None

    # -- moves ----------------------------------------------------------------------------------
    def _moved(self, move: MoveCompleted) -> None:
        """A rotation arrived: the body takes its new cell and orientation; the optical
        switches of everyone change."""
        self._place(self.bodies[move.module], move.to_cell, move.orientation_after)

    def _place(self, b: Body, cell: Cell, orientation: int) -> None:
        old = b.cell
        del self._by_cell[b.cell]
        b.cell, b.orientation = cell, orientation % 6
        self._by_cell[cell] = b
        # light and optical switches change only around the two cells (and the mover turned)
        near = {c for at in (old, cell) for c in (at, *at.neighbours())}
        around = [x.module for c in near if (x := self._by_cell.get(c))]
        if self.core is not None:
            self.core.routes_changed(self, around)
        if b.module in self.own:
            self._publish_pose(b)
        self.publish_switches(set(around))

    def _on_confirm(self, key: str, payload: bytes) -> None:
        """A real module's move, acknowledged and confirmed by its location report: the
        world cannot see real actuators, so it takes the pose it is told (if it is free)."""
        p = Pose.from_json(payload)
        b = self.bodies.get(p.module)
        if b is None or b.kind != "real":
            self.bus.event(WORLD, "bad-confirm", module=p.module,
                           detail="only real modules are confirmed from outside the world")
            return
        before = (b.cell, b.orientation)
        try:
            self.mechanics.judge.relocate(b.module, Cell(p.x, p.y), p.orientation)
        except ValueError as exc:
            self.bus.put(self.bus.keys.world_event, WorldEvent(
                "fault", self.bus.clock.now_ns(), b.module, "confirm-refused",
                {"detail": str(exc), "to": [p.x, p.y]}).to_json())
            return
        self.bus.put(self.bus.keys.world_event, WorldEvent(
            "move-confirmed", self.bus.clock.now_ns(), b.module, "location report",
            {"from": list(before[0]), "to": [p.x, p.y], "orientation_before": before[1],
             "orientation_after": p.orientation % 6, "kind": "real"}).to_json())
        self._place(b, Cell(p.x, p.y), p.orientation)

    # -- ground truth out ----------------------------------------------------------------------
    def start(self) -> None:
        """Publish every pose and optical switch state: at power-up, and again whenever a
        participant that joined late asks on ``world/sync``."""
        for b in self.bodies.values():
            if b.module in self.own:
                self._publish_pose(b)
        self.publish_switches()

    def _publish_pose(self, b: Body) -> None:
        self.bus.put(self.bus.keys.pose(b.module),
                     Pose(b.module, b.id, b.cell.x, b.cell.y, b.orientation,
                          self.bus.clock.now_ns(), b.kind, b.fixed).to_json())

    def at(self, cell: Cell) -> Body | None:
        return self._by_cell.get(cell)

    def switches(self, body: Body) -> list[bool]:
        """Optical switches of a module, in its body frame."""
        return [body.cell.neighbour(body_to_global(s, body.orientation)) in self._by_cell
                for s in range(1, 7)]

    def publish_switches(self, near: set[str] | None = None) -> None:
        """Publish the optical switches of every own module (``near`` None: at power-up and
        on ``world/sync``), or of those in ``near`` whose switches changed since last said: a
        move changes only its neighbourhood, and a switch state holds until changed."""
        now = self.bus.clock.now_ns()
        for b in self.bodies.values():
            if b.module not in self.own or (near is not None and b.module not in near):
                continue
            state = self.switches(b)
            if near is not None and self._switches_said.get(b.module) == state:
                continue
            self._switches_said[b.module] = state
            self.bus.put(self.bus.keys.switches(b.module), Switches(b.module, state, now).to_json())

    # -- the IR medium -------------------------------------------------------------------------------
    def _receivers(self, src: str, transceiver: int) -> list[tuple[str, int]]:
        out = self._all_receivers(src, transceiver)
        if self._whole:
            return out
        return [(d, k) for d, k in out if (self.pc if d == PC else d in self.own)]

    def _all_receivers(self, src: str, transceiver: int) -> list[tuple[str, int]]:
        """Who receives light sent on ``transceiver``. A real module's light here is its
        twin's (:mod:`module_sim.twin`): the twin hears what its board hears from the PC and
        from virtual neighbours, and its side light reaches them; only its centre light
        stays in the world (the PC hears the board itself)."""
        if src == PC or not src.startswith("m"):
            return [(b.module, 0) for b in self.bodies.values()] if transceiver == 0 else []
        me = self.bodies.get(src.split(".")[0])
        if me is None:
            return []
        if transceiver == 0:  # the centre transceivers face the PC's, not each other
            return [(PC, 0)] if me.kind == "virtual" else []
        g = body_to_global(transceiver, me.orientation)
        other = self.at(me.cell.neighbour(g))
        if other is None:
            return []
        return [(other.module, int(global_to_body(Side(g).facing, other.orientation)))]

    def _on_ir(self, key: str, payload: bytes) -> None:
        d = json.loads(payload)
        if self.core is not None:  # the core's medium carries all light (no ber, no mux cut)
            if d.get("type") == "burst":
                self.core.put_light(self, d, self._receivers(d["src"], d["transceiver"]))
            return
        if d.get("type") == "cut":
            # The transmitter's multiplexer switched mid-burst: on the old transceiver the rest of
            # the burst never comes, and the byte being sent is garbled (docs/protocol.md).
            data = bytes.fromhex(d["data"])
            for dst, rx in self._receivers(d["src"], d["transceiver"]):
                air = self._air.get((dst, rx))
                value = None
                if air is not None:
                    value = air.cut(d["src"], d["burst"], data, d["starts"], d["byte_ns"],
                                    d["index"], d["lost_mask"])
                elif d["lost_mask"] is not None:
                    value = data[d["index"]] | d["lost_mask"]
                self.bus.put(self.bus.keys.ir_rx(dst),
                             cut_message(d["src"], d["burst"], d["index"], value, dst=dst))
            return
        src, n, data, starts, byte_ns = d["src"], d["burst"], bytes.fromhex(d["data"]), d["starts"], \
            d["byte_ns"]
        now = self.bus.clock.now_ns() - self.slack_ns  # the air keeps bytes that light may still meet
        bus = self.bus
        clean_head = None
        for dst, rx in self._receivers(src, d["transceiver"]):
            air = self._air.get((dst, rx))
            if air is None:
                air = self._air[(dst, rx)] = Air()
            values, corrupt, fixes, sources = air.collide(src, n, data, starts, byte_ns, now)
            if True in (d.get("corrupt") or ()):  # sent garbled (cut by the transmitter's multiplexer)
                corrupt = [a or b for a, b in zip(corrupt, d["corrupt"])]
            if self.ber:
                flipped = 0
                for i in range(len(values)):
                    for bit in range(8):
                        if self._rng.random() < self.ber:
                            values[i] ^= 1 << bit
                            corrupt[i] = True
                            flipped += 1
                if flipped:  # errors are data: say where the noise struck
                    bus.event(WORLD, "bit-error", receiver=dst, transceiver=rx, sender=src, burst=n,
                              bits=flipped)
            rx_key = bus.keys.ir_rx(dst)
            if fixes:
                bus.put(rx_key, garble_fixes(dst, src, fixes))
            if sources:
                self.collisions += 1
                bus.event(WORLD, "collision", receiver=dst, transceiver=rx,
                          sources=sorted(sources | {src}), received=bytes(values).hex())
            air.add(src, n, data, values, corrupt, starts, byte_ns)
            if True in corrupt:
                bus.put(rx_key, Burst(src, n, d["transceiver"], bytes(values), starts, byte_ns, dst,
                                      rx, corrupt).to_json())
            else:  # the light arrives as sent: encode the common part once for all receivers
                if clean_head is None:
                    clean_head = forwarded(d, len(values))
                bus.put(rx_key, clean_head(dst, rx))

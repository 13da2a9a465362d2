"""Actuation: one planned move becomes frames on the centre channel, then is verified.

For a move of the module at ``mobile`` (Table 4-3 row ``joint``/``direction``, about
``substrate``), thesis Table 3-2 and the latch model (docs/physics.md):

1. every other neighbour of the mobile opens the solenoid whose pin holds the mobile
   (``Select`` + ``JxOpen``), and the mobile opens its own pins into those neighbours;
2. one v2 ``Move(dir, mid, mi, sid, si, t1, t2, t3)`` starts both programs at once
   (``mi``/``si``: :func:`bus.rotations.rotation_arguments`); both ACK, the substrate
   one second later;
3. the neighbours close their solenoids again;
4. verification: the move is compared with the ground truth -- the world's
   ``move-completed`` event and pose for a virtual module -- and the first divergence
   stops the run with a :class:`MoveFailed` naming the module, the move and the cause
   (the world's refusal or fault reason when it gave one).

A real module is verified like a virtual one: the world moves its simulated body from its
board's actuator reports, or from its twin's bits (module_sim.twin). Only with no world on
the bus does its belief follow the acknowledged move and its location report.

A replugged adapter: when the ACKs of a move are missing and a centre serial port went down
after the ``Move`` was sent (the bridge's ``serial-fault``, :class:`PortWatch`), the move
waits for the port to come back (``serial-recovered``, at most :data:`REPLUG_WAIT_S` after
it went down), then asks whether the move happened -- the world's events for the mobile, or
with no world the mobile's location report -- and goes on (it did) or sends the ``Move``
once more (it did not). A port that stays down, or a move whose state cannot be told, ends
the run with a :class:`MoveFailed` that says which.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from bus.codec import encode_command
from bus.errors import HexbenchError
from bus.functions import FunctionCode as F
from bus.lattice import Cell, Direction, Joint, Side
from bus.messages import SERIAL_FAULT, SERIAL_RECOVERED, SERIAL_TX_LOST, Pose, WorldEvent
from bus.rotations import orientation_after, rotation_arguments
from bus.timing import NS_PER_S, THESIS_ROTATION_TIMING
from bus.transport import Bus

from .bringup import BringUp, BringUpError, Fleetview, ModuleState
from .endpoint import ExpectTimeout, PcEndpoint
from .planners.rules import Move

#: Thesis timing of a rotation (§7): t1 = 8, t2 = 4, t3 = 9 ticks.
THESIS_TIMING = THESIS_ROTATION_TIMING
#: How long to wait after the Move ACKs for the world to report the arrival.
SETTLE_S = 2.0
#: How long each of a move's two ACKs is waited for.
ACK_TIMEOUT_S = 5.0
#: How long a move waits for a centre serial port that went down to come back: a replugged
#: USB adapter enumerates again within a few seconds, and the bridge retries at least every
#: 2 s (hil.port.Backoff).
REPLUG_WAIT_S = 10.0
#: The events a serial bridge publishes on ``event/hil.<port>`` (docs/hil.md), as the planner
#: sees them on the bus.
PORT_FAULT, PORT_RECOVERED, PORT_TX_LOST = SERIAL_FAULT, SERIAL_RECOVERED, SERIAL_TX_LOST


class MoveFailed(HexbenchError, RuntimeError):
    """A move that did not happen as planned; ``diagnosis`` says who, what and why."""

    def __init__(self, diagnosis: str, module: int | None = None, move: Move | None = None,
                 cause: str = "") -> None:
        super().__init__(diagnosis)
        self.diagnosis, self.module, self.move, self.cause = diagnosis, module, move, cause


@dataclass
class GroundTruth:
    """What the world publishes, as seen on the bus (virtual modules only)."""

    bus: Bus
    poses: dict[str, Pose] = field(default_factory=dict)
    events: list[WorldEvent] = field(default_factory=list)
    energy_j: float = 0.0

    def __post_init__(self) -> None:
        self.bus.subscribe(self.bus.keys.poses, self._pose)
        self.bus.subscribe(self.bus.keys.world_event, self._event)
        self.bus.subscribe_json(self.bus.keys.world_energy, self._energy)
        self.bus.put_json(self.bus.keys.world_sync, {"from": "planner"})  # a late joiner asks

    def _pose(self, key: str, payload: bytes) -> None:
        p = Pose.from_json(payload)
        self.poses[p.module] = p

    def _event(self, key: str, payload: bytes) -> None:
        self.events.append(WorldEvent.from_json(payload))

    def _energy(self, key: str, d: dict) -> None:
        self.energy_j = max(self.energy_j, float(d.get("run_j", 0.0)))

    def cells(self) -> set[Cell]:
        """The cells the world says are occupied."""
        return {Cell(p.x, p.y) for p in self.poses.values()}

    @property
    def present(self) -> bool:
        """Whether a world publishes on this bus (a fleet of virtual modules)."""
        return bool(self.poses)


@dataclass
class PortWatch:
    """What the serial bridges of the centre channel say about their ports, as seen on the bus
    (a fleet with real modules only: a virtual run has no bridge and no watch)."""

    bus: Bus
    down: dict[str, dict] = field(default_factory=dict)  # bridge name -> its serial-fault event
    up: dict[str, dict] = field(default_factory=dict)  # bridge name -> its last serial-recovered
    faults: list[dict] = field(default_factory=list)
    lost: list[dict] = field(default_factory=list)  # serial-tx-lost events

    def __post_init__(self) -> None:
        self.bus.subscribe_json(f"{self.bus.keys.root}/event/*", self._event)

    def _event(self, key: str, d: dict) -> None:
        kind = d.get("kind")
        if kind not in (PORT_FAULT, PORT_RECOVERED, PORT_TX_LOST) or d.get("link", "centre") != "centre":
            return  # a debug port carries no answers to the PC
        if kind == PORT_FAULT:
            self.down[d["src"]] = d
            self.faults.append(d)
        elif kind == PORT_RECOVERED:
            self.down.pop(d["src"], None)
            self.up[d["src"]] = d
        else:
            self.lost.append(d)

    def fault_since(self, t_ns: int) -> dict | None:
        """The first fault of a port that went down at ``t_ns`` or later, or is down now."""
        return next((d for d in self.faults if d["sim_time_ns"] >= t_ns), None) or \
            next(iter(self.down.values()), None)

    def wait_up(self, until_ns: int) -> bool:
        """Run the clock until every centre port is up again, or ``until_ns``; whether they are."""
        self.bus.clock.run(until=lambda: not self.down, until_ns=until_ns)
        return not self.down

    def sent_lost(self, t_ns: int, data: bytes) -> bool:
        """Whether ``data`` (bytes the PC sent at ``t_ns`` or later) was reported not sent."""
        return any(d["sim_time_ns"] >= t_ns and data.hex() in d.get("lost", "") for d in self.lost)


class Executor:
    """Drives planned moves through the PC endpoint and checks each against the truth."""

    def __init__(self, pc: PcEndpoint, view: Fleetview, bringup: BringUp, truth: GroundTruth,
                 *, timing: tuple[int, int, int] = THESIS_TIMING,
                 say: Callable[[str], None] = print, ports: PortWatch | None = None) -> None:
        self.pc, self.view, self.bringup, self.truth = pc, view, bringup, truth
        self.timing = timing
        self.say = say
        self.ports = ports
        self.moves_done = 0

    def _id_at(self, cell: Cell, what: str, move: Move) -> int:
        m = self.view.at(cell)
        if m is None:
            raise MoveFailed(f"move {move}: the PC believes no module is at {what} {cell}",
                             None, move, "belief")
        return m.id

    def execute(self, move: Move) -> None:
        mid = self._id_at(move.mobile, "the mobile cell", move)
        sid = self._id_at(move.substrate, "the substrate cell", move)
        mob, sub = self.view.modules[mid], self.view.modules[sid]
        rule = move.rule
        mi, si = rotation_arguments(rule, mob.orientation, sub.orientation)
        releases = self._releases(move, mid)
        desc = (f"m{mid} {move.mobile}->{move.goal} ({rule.direction.value} about joint "
                f"{int(rule.joint)}, substrate m{sid} at {move.substrate})")
        self._ports_up(desc, mid, move)
        for ident, body_joint in releases:
            self.bringup.select(ident)
            self.bringup.command(F.JxOpen, body_joint, what=f"m{ident} JxOpen({body_joint})")
        mark_ev = len(self.truth.events)
        mark = len(self.pc.received)
        d = 1 if rule.direction is Direction.CW else 2
        command = encode_command(F.Move, d, mid, mi, sid, si, *self.timing)
        sent_ns = self.pc.bus.clock.now_ns()
        self.pc.send_raw(command)
        real = mob.kind == "real"
        required = real or not self.truth.present
        try:
            if not self._wait_acks(mark, mid, desc, move, required=required, sent_ns=sent_ns):
                self._after_replug(move, mid, desc, command, sent_ns, mark_ev)
        finally:
            for ident, body_joint in releases:
                if ident != mid:
                    self.bringup.select(ident)
                    self.bringup.command(F.JxClose, body_joint, what=f"m{ident} JxClose({body_joint})")
        mob.cell = move.goal
        mob.orientation = orientation_after(mob.orientation, rule.direction)
        if real and not self.truth.present:
            self._confirm_real(move, mob, desc)
        else:  # a world moves every body, a real module's from its board's bits or its twin's
            self._verify(move, mid, desc, mark_ev)
        self.moves_done += 1

    def _confirm_real(self, move: Move, mob: ModuleState, desc: str) -> None:
        """A real module: its location report (v2 keeps it through a Move) must name the
        planned goal; then the world is told where the module is."""
        if mob.localized:
            r = self.bringup.report(mob.id)
            cell, orientation = self.bringup.to_global(r)
            if (cell, orientation) != (move.goal, mob.orientation):
                raise MoveFailed(f"move {desc}: m{mob.id} reports {cell} orientation {orientation}, "
                                 f"planned {move.goal} orientation {mob.orientation}", mob.id, move,
                                 "location report")
        else:
            self.say(f"note: m{mob.id} is real and not localized: its move is confirmed by the "
                     "ACKs alone")
        name = f"m{mob.id}"
        self.pc.bus.put(self.pc.bus.keys.world_confirm, Pose(
            name, mob.id, move.goal.x, move.goal.y, mob.orientation,
            self.pc.bus.clock.now_ns(), "real").to_json())
        if self.truth.present:  # the world takes the pose (or says why not) before we go on
            clock = self.pc.bus.clock

            def taken() -> bool:
                p = self.truth.poses.get(name)
                return p is not None and (p.x, p.y) == tuple(move.goal)
            clock.run(until=taken, until_ns=clock.now_ns() + int(SETTLE_S * NS_PER_S))
            if not taken():
                raise MoveFailed(f"move {desc}: the world did not take m{mob.id}'s confirmed pose "
                                 f"{move.goal}", mob.id, move, "confirm")

    def _releases(self, move: Move, mid: int) -> list[tuple[int, int]]:
        """(module id, body joint) solenoids to open so the mobile can leave: for every
        occupied neighbour other than the substrate, the neighbour's pin at the vertex
        where its facing side ends, and the mobile's own pin where its side ends."""
        out: list[tuple[int, int]] = []
        mob = self.view.modules[mid]
        for s in Side:
            c = move.mobile.neighbour(s)
            n = self.view.at(c)
            if n is None or c == move.substrate:
                continue
            facing = s.facing
            out.append((n.id, int(Joint.of(facing + 1 - n.orientation))))
            out.append((mid, int(Joint.of(s + 1 - mob.orientation))))
        return out

    def _wait_acks(self, mark: int, mid: int, desc: str, move: Move, *, required: bool,
                   sent_ns: int | None = None) -> bool:
        """Both ACKs of a ``Move``; False where they are missing because a centre serial port
        went down after ``sent_ns`` (the caller waits for it: :meth:`_after_replug`)."""
        got: list[int] = []
        try:
            first = self.pc.expect("ack", since=mark, timeout_s=ACK_TIMEOUT_S)
            got.append(first.frame.view.get("byte"))
            nxt = self.pc.received.index(first) + 1
            second = self.pc.expect("ack", since=nxt, timeout_s=ACK_TIMEOUT_S)
            got.append(second.frame.view.get("byte"))
        except ExpectTimeout:
            if sent_ns is not None and self.ports is not None and self.ports.fault_since(sent_ns):
                return False
            noise = [r.frame.raw.hex() for r in self.pc.received[mark:] if r.frame.is_noise]
            cause = "ACK missing" + (f" (noise on the centre channel: {noise})" if noise else "")
            if required:
                raise MoveFailed(f"move {desc}: {cause}; got ACKs {got}", mid, move, cause) from None
            self.say(f"warning: move {desc}: {cause}; checking the world instead")
        return True

    # -- a replugged adapter -------------------------------------------------------------------
    def _ports_up(self, desc: str, mid: int, move: Move) -> None:
        """A centre port that is down before a move starts is waited for (its commands would
        be lost)."""
        fault = self.ports.fault_since(self.pc.bus.clock.now_ns()) if self.ports else None
        if fault is None:
            return
        self.say(f"move {desc}: waiting for serial port {fault['port']}, down for "
                 f"{self._ago(fault)}")
        self._wait_port(fault, desc, mid, move, "before the move")

    def _wait_port(self, fault: dict, desc: str, mid: int, move: Move, when: str) -> float:
        """Wait for the ports to come back, at most :data:`REPLUG_WAIT_S` after ``fault``;
        how long this one was down (s, as its bridge measured it)."""
        if not self.ports.wait_up(fault["sim_time_ns"] + int(REPLUG_WAIT_S * NS_PER_S)):
            cause = f"port down for {self._ago(fault)}"
            raise MoveFailed(f"move {desc}: {cause}: serial port {fault['port']} went away {when} "
                             f"({fault.get('error', '')}) and did not come back within "
                             f"{REPLUG_WAIT_S:g} s", mid, move, cause)
        back = self.ports.up.get(fault["src"])
        if back is not None and back["sim_time_ns"] >= fault["sim_time_ns"]:
            return float(back.get("down_s", 0.0))
        return (self.pc.bus.clock.now_ns() - fault["sim_time_ns"]) / NS_PER_S

    def _ago(self, event: dict) -> str:
        return f"{(self.pc.bus.clock.now_ns() - event['sim_time_ns']) / NS_PER_S:.1f} s"

    def _after_replug(self, move: Move, mid: int, desc: str, command: bytes, sent_ns: int,
                      mark_ev: int) -> None:
        """The ACKs of a ``Move`` were lost to a centre port that went down: wait for it, then
        go on if the move happened, or send the ``Move`` once more if it did not."""
        fault = self.ports.fault_since(sent_ns)
        self.say(f"move {desc}: ACKs missing: serial port {fault['port']} went down during the "
                 f"move ({fault.get('error', '')}); waiting up to {REPLUG_WAIT_S:g} s for it")
        down_s = self._wait_port(fault, desc, mid, move, "during the move")
        done, why = self._move_happened(move, mid, command, sent_ns, mark_ev)
        port = f"serial port {fault['port']} was down for {down_s:.1f} s during the move"
        if done is None:
            raise MoveFailed(f"move {desc}: move state unknown because {why} ({port})", mid, move,
                             "move state unknown")
        if done:
            self.say(f"move {desc}: {port}; it is back and {why}: going on")
            return
        self.say(f"move {desc}: {port}; it is back and {why}: sending the Move once more")
        mark = len(self.pc.received)
        self.pc.send_raw(command)
        self._wait_acks(mark, mid, desc + " (sent again after the port came back)", move,
                        required=True)

    def _move_happened(self, move: Move, mid: int, command: bytes, sent_ns: int,
                       mark_ev: int) -> tuple[bool | None, str]:
        """Whether the mobile made ``move``: True, False, or None (cannot tell), and why."""
        if not self.truth.present:
            return self._reported_at(move, mid)
        name = f"m{mid}"
        clock = self.pc.bus.clock
        ends = ("move-completed", "move-refused", "fault")

        def mine() -> list[WorldEvent]:
            return [e for e in self.truth.events[mark_ev:] if e.module == name]

        # a move still on its way ends within the ACK window and the settling time after it
        until = max(clock.now_ns(), sent_ns + int(2 * ACK_TIMEOUT_S * NS_PER_S)) + int(SETTLE_S * NS_PER_S)
        clock.run(until=lambda: any(e.kind in ends for e in mine()), until_ns=until)
        seen = [e.kind for e in mine()]
        lost = self.ports.sent_lost(sent_ns, command)
        if any(k in ends for k in seen):
            if lost:  # a twin hears the PC's light, sent or not
                return None, (f"the bridge could not send the Move to the board, yet the world (a "
                              f"twin) made it: {', '.join(seen)}")
            return True, f"the world saw {name}'s move end ({', '.join(seen)})"
        if seen:
            return None, f"the world saw {name} start the move ({', '.join(seen)}) but not end it"
        return False, f"the world saw no move of {name}"

    def _reported_at(self, move: Move, mid: int) -> tuple[bool | None, str]:
        """No world: the mobile's location report, at the goal or still at the start."""
        mob = self.view.modules[mid]
        if not mob.localized:
            return None, f"m{mid} is not localized, so its location report cannot say where it is"
        try:
            cell, _ = self.bringup.to_global(self.bringup.report(mid))
        except BringUpError as exc:
            return None, f"m{mid} sent no location report ({exc})"
        if cell == move.goal:
            return True, f"m{mid} reports the goal {cell}"
        if cell == move.mobile:
            return False, f"m{mid} reports it is still at {cell}"
        return None, f"m{mid} reports {cell}, neither its start {move.mobile} nor the goal {move.goal}"

    def _verify(self, move: Move, mid: int, desc: str, mark_ev: int) -> None:
        if not self.truth.present:
            return
        name = f"m{mid}"
        clock = self.pc.bus.clock
        deadline = clock.now_ns() + int(SETTLE_S * NS_PER_S)

        def settled() -> bool:
            return any(e.module == name and e.kind in ("move-completed", "move-refused", "fault")
                       for e in self.truth.events[mark_ev:])
        clock.run(until=settled, until_ns=deadline)
        mine = [e for e in self.truth.events[mark_ev:] if e.module == name]
        done = [e for e in mine if e.kind == "move-completed"]
        if not done:
            bad = [e for e in self.truth.events[mark_ev:] if e.kind in ("move-refused", "fault")]
            if bad:
                e = next((x for x in bad if x.module == name), bad[0])
                cause = f"{e.kind} {e.reason}: {e.data.get('detail', '')}"
            else:
                cause = "the world reports no move at all (no drive reached the modules)"
            raise MoveFailed(f"move {desc} failed: {cause}", mid, move, cause)
        to = done[-1].data.get("to")
        pose = self.truth.poses.get(name)
        if to != [move.goal.x, move.goal.y] or pose is None or (pose.x, pose.y) != tuple(move.goal):
            raise MoveFailed(f"move {desc}: the world put m{mid} at {to}, planned {move.goal}",
                             mid, move, "diverged")
        belief = self.view.modules[mid].orientation
        if pose.orientation != belief:
            raise MoveFailed(f"move {desc}: m{mid} arrived with orientation {pose.orientation}, "
                             f"the PC believes {belief}", mid, move, "diverged")

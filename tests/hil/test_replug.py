"""A replugged adapter in mid-move does not end the run (issue 42; docs/hil.md "Faults and
recovery").

``hexbench run pair --clock wall --real 2=<pty>,<debug pty>`` in its own process; module 2, the
mobile of the pair's one move, is a :class:`StandIn` in this process. The moment the stand-in
hears a ``Move`` naming it, its centre line is hung up (the adapter pulled): the board makes the
move and its ACK goes out to nobody. In one run the line comes back 1 s after that ACK, and the
run must still reach the goal; in the other it never comes back, and the run must end in bounded
time with one line saying why.

Both runs start together (a module fixture), so the file costs one run's time. No sleeps: the
hang-up and the replug are triggered by what the stand-in hears and says, on its own clock, and
every wait has a timeout.

The executor's other answers to a port that went down (the Move sent once more where the world
saw no move, a move whose state cannot be told) are held on a virtual clock, the bridge's
events and the world's scripted on the bus, in milliseconds.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from mcap.reader import make_reader

from bus.clock import VirtualClock
from bus.codec import Kind, Link, encode_ack
from bus.framer import Framer
from bus.functions import FunctionCode as F
from bus.ir import Burst
from bus.keys import PC, board_endpoint, module_endpoint
from bus.lattice import Cell
from bus.messages import Pose, WorldEvent
from bus.rotations import orientation_after
from bus.scenario import load
from bus.session import SessionOptions
from bus.timing import NS_PER_S
from bus.transport import Bus
from hexbench.standin import StandIn
from hil import bridge
from planner_svc import planners
from planner_svc.bringup import BringUp, Fleetview, ModuleState
from planner_svc.endpoint import PcEndpoint
from planner_svc.executor import (PORT_FAULT, PORT_RECOVERED, PORT_TX_LOST, REPLUG_WAIT_S, Executor,
                                  GroundTruth, MoveFailed, PortWatch)

REAL = 2  # the pair's mobile
RUN_TIMEOUT_S = 300.0
#: From the board's Move ACK (lost) to the replug: the bridge is down for about this much more.
REPLUG_AFTER_S = 1.0


@dataclass
class Replug:
    """One run whose real module's centre line is pulled at its first Move; ``reopen``: plugged
    back in ``REPLUG_AFTER_S`` after the board's ACK of that Move."""

    name: str
    reopen: bool
    dir: Path = Path()
    standin: StandIn | None = None
    proc: subprocess.Popen | None = None
    hung_up_at: float | None = None  # time.monotonic()
    reopened_at: float | None = None
    ended_at: float | None = None
    out: str = ""
    code: int | None = None
    ended: threading.Event = field(default_factory=threading.Event)
    _framer: Framer = field(default_factory=lambda: Framer(Link.PC))

    def start(self, base: Path) -> None:
        self.dir = base / self.name
        self.dir.mkdir()
        link, dlink = self.dir / "m2", self.dir / "m2d"
        self.standin = s = StandIn.on_pty(link, debug_link=dlink, module_id=REAL).start()
        s.bus.subscribe(s.bus.keys.ir_rx(module_endpoint(REAL)), self._heard)
        s.bus.subscribe_frames(self._said, keyexpr=s.bus.keys.frame("centre", board_endpoint(REAL, "comm")))
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hexbench", "run", "pair", "--planner", "thesis-serial",
             "--clock", "wall", "--real", f"{REAL}={link},{dlink}", "--record", "run.mcap",
             "--isolated", "--fleet", f"replug-{self.name}"],
            cwd=self.dir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"})
        threading.Thread(target=self._collect, daemon=True, name=f"replug-{self.name}").start()

    def _collect(self) -> None:
        try:
            self.out, _ = self.proc.communicate(timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.out = (self.proc.communicate()[0] or "") + f"\n(killed after {RUN_TIMEOUT_S} s)"
        self.code = self.proc.returncode
        self.ended_at = time.monotonic()
        (self.dir / "out.txt").write_text(self.out)  # beside run.mcap, for a post-mortem
        self.ended.set()

    # -- the stand-in's clock thread -------------------------------------------------------------
    def _heard(self, key: str, payload: bytes) -> None:
        """Light from the line: the first Move naming the board pulls the cable."""
        if self.hung_up_at is not None:
            return
        for t in self._framer.feed(Burst.from_dict(json.loads(payload)).data):
            v = t.frame.view
            if t.frame.kind is Kind.COMMAND and v.get("code") == F.Move and \
                    REAL in (v["args"].get("mid"), v["args"].get("sid")):
                self.standin.hangup()
                self.hung_up_at = time.monotonic()
                return

    def _said(self, env) -> None:
        """The board's ACK of that Move (its MCW/MCCW code) went out to nobody: plug the cable
        back in a little later."""
        if self.reopen and self.hung_up_at is not None and self.reopened_at is None and \
                env.kind == "ack":
            self.reopened_at = -1.0  # scheduled
            self.standin.clock.call_later(int(REPLUG_AFTER_S * 1e9), self._reopen)

    def _reopen(self) -> None:
        self.standin.reopen()
        self.reopened_at = time.monotonic()

    # -- results ---------------------------------------------------------------------------------
    def wait(self) -> "Replug":
        assert self.ended.wait(RUN_TIMEOUT_S + 30), f"{self.name}: the run did not end"
        return self

    def records(self) -> list[tuple[str, dict]]:
        with open(self.dir / "run.mcap", "rb") as f:
            return [(ch.topic, json.loads(m.data)) for _, ch, m in make_reader(f).iter_messages()
                    if ch.message_encoding == "json"]

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
        if self.standin is not None:
            self.standin.close()


@pytest.fixture(scope="module")
def replugs(tmp_path_factory):
    base = tmp_path_factory.mktemp("replug")
    rigs = {"back": Replug("back", reopen=True), "gone": Replug("gone", reopen=False)}
    try:
        for rig in rigs.values():
            rig.start(base)
        yield rigs
    finally:
        for rig in rigs.values():
            rig.close()


def test_a_replugged_adapter_mid_move_does_not_end_the_run(replugs):
    run = replugs["back"].wait()
    assert run.hung_up_at is not None and run.reopened_at is not None, run.out
    assert run.code == 0, run.out
    lines = run.out.splitlines()
    assert lines[-2].startswith("thesis-serial: goal reached") and "moves 1 " in lines[-2], run.out
    # the executor waited for the port instead of failing at the ACK timeout, then asked the world
    assert "ACKs missing: serial port" in run.out and "went down during the move" in run.out
    (decided,) = [ln for ln in lines if "it is back and" in ln]
    assert "the world saw m2's move end (move-started, move-completed)" in decided, decided
    assert decided.endswith("going on"), decided
    recs = run.records()
    kinds = [d["kind"] for t, d in recs if t == "event/hil.m2"]
    assert kinds.count(PORT_FAULT) == 1 and kinds.count(PORT_RECOVERED) == 1, kinds
    assert PORT_TX_LOST not in kinds  # the PC sent nothing while the port was down
    (fault,) = [d for t, d in recs if t == "event/hil.m2" and d["kind"] == PORT_FAULT]
    assert fault["link"] == "centre"
    # the move was made once, not sent again
    moved = [d for t, d in recs if t == "world/event" and d["kind"] == "move-completed"]
    assert [d["module"] for d in moved] == ["m2"] and moved[0]["data"]["to"] == [0, 1]
    moves = [d for t, d in recs if t == "frame/pc/pc" and d["kind"] == "command"
             and bytes.fromhex(d["raw"])[1] == F.Move]
    assert len(moves) == 1
    # the board's ACK that nobody heard is not a divergence: its twin's was left out
    assert not [d for t, d in recs if t.startswith("event/") and d["kind"] == "twin-diverged"]
    (centre,) = [ln for ln in lines if ln.startswith("twin check m2 (centre)")]
    assert "no divergence" in centre and "not compared: the board's port was down" in centre, centre


def test_a_port_that_never_comes_back_ends_the_run_with_one_line(replugs):
    run = replugs["gone"].wait()
    assert run.hung_up_at is not None, run.out
    assert run.code == 1, run.out
    assert "Traceback" not in run.out
    failed = [ln for ln in run.out.splitlines() if ln.startswith("thesis-serial: FAILED")]
    assert len(failed) == 1, run.out
    (line,) = failed
    port = str(run.dir / "m2")
    assert re.search(rf"move m2 \S+->\S+ .*: port down for 1\d\.\d s: serial port {re.escape(port)} "
                     rf"went away during the move \(.+\) and did not come back within "
                     rf"{REPLUG_WAIT_S:g} s; steps 0, moves 0 ", line), line
    # it waited for the port (not the ACK timeout alone), and not much longer
    took = run.ended_at - run.hung_up_at
    assert REPLUG_WAIT_S <= took < REPLUG_WAIT_S + 40, took


# -- the decisions, on a virtual clock ---------------------------------------------------------------
def test_the_planner_reads_the_bridges_event_kinds():
    assert (PORT_FAULT, PORT_RECOVERED, PORT_TX_LOST) == (bridge.FAULT, bridge.RECOVERED, bridge.TX_LOST)


class Scripted:
    """The pair's one move as the PC sees it in a mixed run: m2 real behind ``hil.m2``, m1 virtual,
    a world. Each Move the PC sends gets the next entry of ``script``, a set of what happens:
    ``fault`` (the port goes down as the Move ends, back 2 s later), ``lost`` (the bridge could
    not send the Move), ``acks`` (both modules answer), ``world`` (the world moves m2)."""

    def __init__(self, script: list[set[str]]) -> None:
        self.script, self.moves = script, 0
        self.clock = VirtualClock()
        self.bus = Bus(self.clock, f"replug{id(self)}", options=SessionOptions(isolated=True))
        sc = load("pair")
        self.move = planners.get("thesis-serial").plan(sc).steps[0][0]
        self.pc = PcEndpoint(self.bus)
        truth = GroundTruth(self.bus)
        self.said: list[str] = []
        view = Fleetview({1: ModuleState(1, Cell(0, 0), 0, True, "virtual"),
                          2: ModuleState(2, Cell(1, 0), 0, True, "real")})
        self.executor = Executor(self.pc, view, BringUp(self.pc, sc, say=self.said.append), truth,
                                 say=self.said.append, ports=PortWatch(self.bus))
        self.bus.subscribe(self.bus.keys.ir_tx(PC), self._on_pc_light)
        for m in sc.modules:
            self._pose(m.id, m.cell, m.orientation)

    def _pose(self, ident: int, cell: Cell, orientation: int) -> None:
        self.bus.put(self.bus.keys.pose(f"m{ident}"), Pose(
            f"m{ident}", ident, cell.x, cell.y, orientation, self.clock.now_ns(),
            "real" if ident == REAL else "virtual").to_json())

    def _port(self, kind: str, **fields) -> None:
        self.bus.event("hil.m2", kind, port="/dev/ttyUSB0", link="centre", **fields)

    def _on_pc_light(self, key: str, payload: bytes) -> None:
        burst = Burst.from_dict(json.loads(payload))
        if burst.data[1] != F.Move:
            return
        what = self.script[self.moves]
        self.moves += 1
        end, at = burst.starts[-1] + burst.byte_ns, self.clock.call_at
        if "fault" in what:
            at(end, lambda: self._port(PORT_FAULT, error="pulled"))
            at(end + 2 * NS_PER_S, lambda: self._port(PORT_RECOVERED, down_s=2.0))
        if "lost" in what:
            at(end, lambda: self._port(PORT_TX_LOST, lost=burst.data.hex()))
        if "acks" in what:  # the mobile at once, the substrate a second later
            at(end, self._ack, "m2.comm", b"M: ", 22)
            at(end + NS_PER_S, self._ack, "m1.comm", b"S: ", 24)
        if "world" in what:
            at(end + NS_PER_S // 2, self._moved)

    def _ack(self, src: str, role: bytes, code: int) -> None:
        data = encode_ack(code, role=role)
        now, b = self.clock.now_ns(), self.pc.byte_ns
        self.bus.put(self.bus.keys.ir_rx(PC), Burst(src, self.moves, 0, data, [now + k * b for k in range(len(data))],
                                                    b, dst=PC).to_json())

    def _moved(self) -> None:
        goal, o = self.move.goal, orientation_after(0, self.move.rule.direction)
        self.bus.put(self.bus.keys.world_event, WorldEvent(
            "move-completed", self.clock.now_ns(), "m2", "", {"to": [goal.x, goal.y]}).to_json())
        self._pose(REAL, goal, o)

    def execute(self) -> None:
        try:
            self.executor.execute(self.move)
        finally:
            self.bus.close()


def test_a_move_the_world_never_saw_is_sent_once_more_when_the_port_is_back():
    run = Scripted([{"fault"}, {"acks", "world"}])
    run.execute()
    assert run.moves == 2 and run.executor.moves_done == 1
    assert "the world saw no move of m2: sending the Move once more" in run.said[-1]


def test_a_move_the_board_never_got_but_its_twin_made_is_unknown():
    run = Scripted([{"fault", "lost", "world"}])
    with pytest.raises(MoveFailed) as exc:
        run.execute()
    assert run.moves == 1
    assert exc.value.cause == "move state unknown"
    assert ": move state unknown because the bridge could not send the Move to the board, yet the " \
           "world (a twin) made it: move-completed (serial port /dev/ttyUSB0 was down for 2.0 s " \
           "during the move)" in str(exc.value)


def test_a_move_sent_again_must_be_acknowledged():
    run = Scripted([{"fault"}, {"fault"}])
    with pytest.raises(MoveFailed, match=r"\(sent again after the port came back\).*: ACK missing"):
        run.execute()
    assert run.moves == 2

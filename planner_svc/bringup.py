"""Bring-up: from a powered fleet to the initial configuration I, over the centre channel.

v2 modules: wait for the boot to finish; make the fixed module the reference (``Ref``);
run one ``Localize`` step per ring of the declared I around it (one step localizes one ring
for everyone); ``Select`` each module by id and read its ``Report`` once; build I from the
reports. A module still not localized then (I is not as declared) gets more steps and is
asked again, alone: O(n + d) frames for n modules and d rings.
thesis-2009 modules cannot be addressed or read back: I comes from the scenario, and
the bring-up says so.

Positions come back in the reference's frame (it is (0,0), Yref 0 after ``Ref``). They
are turned into the scenario's global frame with the fixed cell and the reference's
declared orientation (:func:`bus.lattice.rotate_offset`).

A real board beside virtual neighbours hears none of their side light, so it cannot be
localized by them; its twin in the world (:mod:`module_sim.twin`) can. Where the board
reports L=0 and its twin, answering the same ``Report``, L=1, the twin's report is used and
the bring-up says so (the twin check records it as a ``twin-view`` event).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from bus.codec import Kind, Link
from bus.envelope import Envelope
from bus.errors import HexbenchError
from bus.functions import FunctionCode as F
from bus.lattice import Cell, rings, rotate_offset
from bus.scenario import Scenario
from bus.timing import NS_PER_S, TICK_NS, localize_step_ticks

from .endpoint import ExpectTimeout, PcEndpoint

#: The last boot banner (COMM. LISTENING) ends at ~7.5 s after power-up (docs/protocol.md).
BOOT_S = 9.0
#: Select modes (v2 code 60).
SELECT_ALL, SELECT_ID, SELECT_NONE = 0, 1, 4
RETRIES = 3


class BringUpError(HexbenchError, RuntimeError):
    """The fleet could not be brought up; the message names the module and the cause."""


@dataclass
class ModuleState:
    """What the PC believes about one module."""

    id: int
    cell: Cell
    orientation: int  # global side = body side + orientation
    localized: bool = False
    kind: str = "virtual"


@dataclass
class Fleetview:
    """The PC's belief: every module by id, and the cells they occupy."""

    modules: dict[int, ModuleState] = field(default_factory=dict)
    source: str = ""  # "location reports" or "scenario"

    def at(self, cell: Cell) -> ModuleState | None:
        return next((m for m in self.modules.values() if m.cell == cell), None)

    def cells(self) -> frozenset[Cell]:
        return frozenset(m.cell for m in self.modules.values())


class BringUp:
    """Runs the bring-up of a fleet through a :class:`PcEndpoint`."""

    def __init__(self, pc: PcEndpoint, scenario: Scenario, *, profile: str | None = None,
                 say: Callable[[str], None] = print) -> None:
        self.pc = pc
        self.scenario = scenario
        self.profile = profile or scenario.profile
        self.say = say
        self.localize_steps = 0
        self.kinds = {m.id: m.kind for m in scenario.modules}
        self.twins: set[int] = set()  # real modules whose twin is heard on the bus
        self._twin_report: dict[int, Envelope] = {}
        pc.bus.subscribe_frames(self._on_centre, Link.CENTRE.value)

    def _on_centre(self, env: Envelope) -> None:
        if env.origin != "twin":
            return
        ident = int(env.src[1:].split(".")[0])
        self.twins.add(ident)
        if env.kind == Kind.POSITION.value:
            self._twin_report[ident] = env

    # -- helpers ---------------------------------------------------------------------------------
    def command(self, fn: int, *args: int, timeout_s: float = 5.0, what: str = "") -> None:
        """Send and wait for the ACK of ``fn``, retrying lost answers (all bring-up
        commands are idempotent)."""
        last = ""
        for _ in range(RETRIES):
            mark = len(self.pc.received)
            self.pc.send(fn, *args)
            try:
                self.pc.expect("ack", since=mark, timeout_s=timeout_s, byte=int(fn))
                return
            except ExpectTimeout as exc:
                last = str(exc)
        raise BringUpError(f"{what or F(fn).name}: no ACK {int(fn)} after {RETRIES} tries ({last})")

    def select(self, ident: int) -> None:
        self.command(F.Select, SELECT_ID, ident, 0, what=f"Select(m{ident})")

    def report(self, ident: int) -> dict:
        last = ""
        for _ in range(RETRIES):
            self.select(ident)
            mark = len(self.pc.received)
            self.pc.send(F.Report)
            sent = self.pc.bus.clock.now_ns()
            try:
                r = self.pc.expect("position", since=mark, timeout_s=5.0, id=ident)
                # the ACK follows the report: a module still talking misses the next frame
                self.pc.expect("ack", since=self.pc.received.index(r) + 1, timeout_s=5.0,
                               byte=int(F.Report))
                return self._or_twins(ident, dict(r.frame.view), sent)
            except ExpectTimeout as exc:
                last = str(exc)
        raise BringUpError(f"m{ident}: no location report after {RETRIES} tries ({last})")

    def _or_twins(self, ident: int, report: dict, sent_ns: int) -> dict:
        """A real board's report, or its twin's answer to the same ``Report`` where only the
        twin is localized (it heard neighbours the board cannot)."""
        twin = self._twin_report.get(ident)
        if report["localized"] or twin is None or twin.sim_time_ns < sent_ns:
            return report
        view = dict(twin.frame.view)
        if not view.get("localized"):
            return report
        self.say(f"bring-up: m{ident} (real) is not localized on its board, which hears no "
                 f"virtual neighbour: using its twin's report x={view['x']} y={view['y']} "
                 f"yref={view['yref']}")
        view["source"] = "twin"
        return view

    # -- the bring-up ----------------------------------------------------------------------------
    def wait_boot(self, since_ns: int = 0) -> None:
        clock = self.pc.bus.clock
        until = since_ns + int(BOOT_S * NS_PER_S)
        clock.run(until_ns=until, until=lambda: clock.now_ns() >= until)
        banners = [r for r in self.pc.received if r.frame.kind.value == "banner"]
        noise = sum(1 for r in self.pc.received if r.frame.is_noise)
        self.say(f"bring-up: boot done at {(clock.now_ns() - clock.started_ns) / NS_PER_S:.1f} s: {len(banners)} banners "
                 f"intact, {noise} noise frames (banners of modules booting together collide)")

    def _elapsed_s(self) -> float:
        clock = self.pc.bus.clock
        return (clock.now_ns() - clock.started_ns) / NS_PER_S

    def run(self, since_ns: int = 0) -> Fleetview:
        self.wait_boot(since_ns)
        if self.profile == "thesis-2009":
            return self.from_scenario("thesis-2009 modules have no addressing and no location "
                                      "report")
        virtual_or_real = {m.id: m.kind for m in self.scenario.modules}
        ref = self.scenario.fixed_module
        n = len(virtual_or_real)
        self.select(ref.id)
        self.command(F.Ref, what=f"Ref(m{ref.id})")
        reports = {ref.id: self.report(ref.id)}
        # One step localizes one ring for everyone at once: the PC runs as many steps as I
        # has rings around the reference and reads the fleet back once, O(n + d) frames.
        # Polling every module after every step was O(n * d): 49 % of a 217-module run.
        depth = max(rings(self.scenario.fixed, (m.cell for m in self.scenario.modules)).values())
        self.say(f"bring-up: m{ref.id} is the reference at {self._elapsed_s():.1f} s; "
                 f"{depth} ring(s) around it to localize")
        for _ in range(depth):
            self.localize_step()
            self.say(f"bring-up: Localize step {self.localize_steps} of {depth} done at "
                     f"{self._elapsed_s():.1f} s")
        # the read-back: every module answers (it is powered and addressable) with its place
        reports.update((i, self.report(i)) for i in sorted(virtual_or_real) if i != ref.id)
        self.say(f"bring-up: {n} modules read back at {self._elapsed_s():.1f} s")
        while True:
            pending = [i for i in sorted(reports) if not reports[i]["localized"]]
            # a real board cannot exchange side IR with virtual neighbours (docs/hil.md): it
            # is waited for where its twin can be localized in its place
            if not [i for i in pending if virtual_or_real[i] == "virtual" or i in self.twins]:
                break
            if self.localize_steps >= max(n, depth + 1):
                raise BringUpError(f"localization: {', '.join(f'm{i}' for i in pending)} still not "
                                   f"localized after {self.localize_steps} steps (not connected to "
                                   "the reference, or their side IR links fail)")
            # I is not what the scenario says (or a link lost a message): one more step, and
            # only the modules still pending are asked again
            self.localize_step()
            for i in pending:
                reports[i] = self.report(i)
            done = sum(1 for r in reports.values() if r["localized"])
            self.say(f"bring-up: extra Localize step {self.localize_steps}: {done} of {n} modules "
                     f"localized at {self._elapsed_s():.1f} s")
        done = sum(1 for r in reports.values() if r["localized"])
        self.say(f"bring-up: localized {done} of {n} modules in {self.localize_steps} Localize step(s) "
                 f"at {self._elapsed_s():.1f} s")
        view = Fleetview(source="location reports")
        for i, r in reports.items():
            if not r["localized"]:
                spec = next(m for m in self.scenario.modules if m.id == i)
                self.say(f"bring-up: m{i} ({spec.kind}) could not be localized: taking its pose "
                         f"{spec.cell} orientation {spec.orientation} from the scenario")
                view.modules[i] = ModuleState(i, spec.cell, spec.orientation, False, spec.kind)
                continue
            cell, orientation = self.to_global(r)
            view.modules[i] = ModuleState(i, cell, orientation, True, virtual_or_real[i])
        return view

    def to_global(self, report: dict) -> tuple[Cell, int]:
        """A location report (reference frame) as a cell and orientation of the scenario."""
        o_ref = self.scenario.fixed_module.orientation
        dx, dy = rotate_offset((report["x"], report["y"]), o_ref)
        return Cell(self.scenario.fixed.x + dx, self.scenario.fixed.y + dy), (report["yref"] + o_ref) % 6

    def localize_step(self) -> None:
        """One v2 ``Localize`` broadcast; returns when the step's slots have all passed."""
        # a broadcast is executed by everyone and answered by no one (docs/protocol.md)
        self.pc.send(F.Select, SELECT_ALL, 0, 0)
        self.pc.send(F.Localize)
        clock = self.pc.bus.clock
        end = self.pc.line_free_at + (localize_step_ticks(self.scenario.ir_baud) + 5) * TICK_NS
        clock.run(until_ns=end, until=lambda: clock.now_ns() >= end)
        self.localize_steps += 1

    def from_scenario(self, why: str) -> Fleetview:
        self.say(f"bring-up: {why}: taking the initial configuration from scenario "
                 f"{self.scenario.name!r}")
        return Fleetview({m.id: ModuleState(m.id, m.cell, m.orientation, False, m.kind)
                          for m in self.scenario.modules}, "scenario")

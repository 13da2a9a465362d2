"""A fleet: the world, a virtual module for every virtual module of a scenario, and a twin
(:mod:`module_sim.twin`) for every real one. On the wall clock it watches its own lag
(:class:`LagWatch`)."""

from __future__ import annotations

import dataclasses
import gc
import random
from typing import TYPE_CHECKING

from bus.cheader import FirmwareError
from bus.clock import VirtualClock, WallClock
from bus.keys import module_endpoint
from bus.scenario import Scenario
from bus.timing import NS_PER_S, TICK_NS, Baud
from bus.transport import Bus

from .module import VirtualModule
from .profiles import profile
from .shards import partition
from .world import World

if TYPE_CHECKING:
    from .core import FleetCore


#: Lateness past which a wall-clock fleet has fallen behind: two ticks (a tick is 9.984 ms).
LAG_THRESHOLD_NS = 20_000_000
#: How often the fleet looks at its clock's lateness.
LAG_CHECK_NS = 100_000_000
#: At most one ``lag`` event this often; each has the worst lateness since the one before.
LAG_EVENT_EVERY_NS = NS_PER_S
#: The participant whose events (``event/fleet``) say the fleet's lag.
LAG_SRC = "fleet"


class LagWatch:
    """A wall-clock fleet's lag, as Gazebo shows its real-time factor: how late its clock runs
    timers and deliveries (:meth:`bus.clock.WallClock.take_lateness`). A span in which they ran
    more than :data:`LAG_THRESHOLD_NS` late becomes a ``lag`` event on ``event/fleet`` once it
    is over (or every :data:`LAG_EVENT_EVERY_NS` while it lasts, no more often): ``late_ns``
    (the worst), ``timer_late_ns``, ``delivery_late_ns``, ``threshold_ns``. A virtual clock has
    no lag: its time waits for the work."""

    def __init__(self, bus: Bus) -> None:
        self.bus = bus
        self.clock = bus.clock
        self._timer_ns = self._delivery_ns = 0  # the worst of the span not yet published
        self._span_ns: int | None = None  # when the checks first saw it
        self._last_event_ns: int | None = None

    def start(self) -> "LagWatch":
        self.clock.take_lateness()  # what came before the fleet ran is not its lag
        self.clock.call_later(LAG_CHECK_NS, self._check)
        return self

    def _check(self) -> None:
        self.clock.call_later(LAG_CHECK_NS, self._check)
        timer, delivery = self.clock.take_lateness()
        now = self.clock.now_ns()
        behind = max(timer, delivery) > LAG_THRESHOLD_NS
        if behind and self._span_ns is None:
            self._span_ns = now
        if self._span_ns is None:
            return
        # a span's worst comes after the check that first saw it (timers due later in it run later)
        self._timer_ns, self._delivery_ns = max(self._timer_ns, timer), max(self._delivery_ns, delivery)
        over = not behind or now - self._span_ns >= LAG_EVENT_EVERY_NS
        if over and (self._last_event_ns is None or now - self._last_event_ns >= LAG_EVENT_EVERY_NS):
            self.bus.event(LAG_SRC, "lag", late_ns=max(self._timer_ns, self._delivery_ns),
                           timer_late_ns=self._timer_ns, delivery_late_ns=self._delivery_ns,
                           threshold_ns=LAG_THRESHOLD_NS)
            self._last_event_ns = now
            self._timer_ns = self._delivery_ns = 0
            self._span_ns = None if not behind else now


class Fleet:
    def __init__(self, bus: Bus, scenario: Scenario, *, profile_name: str | None = None,
                 mux_cut: bool = False, shard: tuple[int, int] | None = None,
                 slack_ns: int = 0, core: bool = True) -> None:
        """``shard=(k, n)``: only part ``k`` of ``n`` (:func:`module_sim.shards.partition`):
        its modules and its part of the world, for a fleet spread over processes on a
        lockstep clock; ``slack_ns`` how late light from other shards may arrive.
        ``core``: run the firmware-program modules and the IR medium in the fleet core
        (:mod:`module_sim.core`) where it can (:meth:`core_refusal`); False: the Python path."""
        self.bus = bus
        self.profile = profile(profile_name or scenario.profile)
        #: why a scenario that names no program runs the Python programs (None: it does not)
        self.program_note: str | None = None
        if scenario.program is None:
            scenario, self.program_note = self.default_program(
                bus, scenario, mux_cut, self.profile.name,
                refusal="the fleet was made for the Python path" if not core else
                "a shard's fleet runs on a lockstep clock" if shard is not None else None)
        self.scenario = scenario
        self.shard = shard
        mine = {m.id for m in scenario.modules}
        if shard is not None:
            k, n = shard
            parts = partition([m.cell for m in scenario.modules], n, seed=scenario.seed)
            mine = {m.id for m, p in zip(scenario.modules, parts) if p == k}
            self.world = World(bus, scenario, own={module_endpoint(i) for i in mine}, pc=False,
                               slack_ns=slack_ns)
        else:
            self.world = World(bus, scenario)
        #: the fleet core (module_sim.core) running the firmware-program modules, if it can
        self.core = self._core(bus, scenario, mux_cut) if core and shard is None else None
        self.modules = {m.id: VirtualModule(bus, m.id, self.profile, ir_baud=scenario.ir_baud,
                                            mux_cut=mux_cut, program=scenario.program_of(m),
                                            core=self.core)
                        for m in scenario.modules if m.kind == "virtual" and m.id in mine}
        if self.core is not None:
            self.core.add_fleet(bus, self.world, list(self.modules.values()))
        # every virtual module, for the power-up phases: a shard draws them all, in order
        self._virtual = sorted(m.id for m in scenario.modules if m.kind == "virtual")
        self.twins = {m.id: VirtualModule(bus, m.id, self.profile, ir_baud=scenario.ir_baud,
                                          mux_cut=mux_cut, origin="twin")
                      for m in scenario.modules if m.kind in ("real", "firmware")}
        self.lag = LagWatch(bus) if isinstance(bus.clock, WallClock) else None

    @staticmethod
    def default_program(bus: Bus, scenario: Scenario, mux_cut: bool = False, profile: str | None = None,
                        refusal: str | None = None) -> tuple[Scenario, str | None]:
        """``scenario`` with the default program made explicit (bus.scenario: its ``program``
        None): the C firmware on the fleet core where it can run this fleet, else the Python
        programs and one line saying why (``refusal``: a reason the caller knows already)."""
        if scenario.program is not None:
            return scenario, None
        if refusal is None and scenario.ir_baud != Baud.IR:
            refusal = f"the C programs are built for {int(Baud.IR)} baud IR, not {scenario.ir_baud}"
        if refusal is None:
            firmware = dataclasses.replace(scenario, program="firmware")
            try:
                refusal = Fleet.core_refusal(bus, firmware, mux_cut, profile)
            except FirmwareError as exc:  # no host build of the firmware or of the core here
                refusal = str(exc)
            if refusal is None:
                return firmware, None
        return (dataclasses.replace(scenario, program="model"),
                f"program: the Python programs, not the C firmware on the fleet core: {refusal}")

    @staticmethod
    def core_refusal(bus: Bus, scenario: Scenario, mux_cut: bool = False,
                     profile: str | None = None) -> str | None:
        """Why the fleet core cannot run this fleet (None: it can): what only the Python
        path has."""
        core = Fleet._core_or_refusal(bus, scenario, mux_cut, profile or scenario.profile)
        return core if isinstance(core, str) else None

    @staticmethod
    def _core_or_refusal(bus: Bus, scenario: Scenario, mux_cut: bool, profile: str) -> "FleetCore | str":
        """The clock's fleet core for this fleet (made on first use), or why it cannot be."""
        if type(bus.clock) is not VirtualClock:  # a lockstep clock's windows are the shards'
            what = "a wall clock" if isinstance(bus.clock, WallClock) else "a lockstep clock (shards)"
            return f"{what}: the core runs on the virtual clock of one process"
        if mux_cut:
            return "a multiplexer that cuts bursts (--mux-cut) is modelled in Python only"
        if scenario.bit_error_rate:
            return "bit errors are drawn in Python only"
        if not any(m.kind == "virtual" and scenario.program_of(m) == "firmware" for m in scenario.modules):
            return "no virtual module runs the firmware program"
        others = sorted({scenario.program_of(m) for m in scenario.modules if m.kind == "virtual"}
                        - {"firmware"})
        if others:
            names = {"model": "the Python programs", "simavr": "the images in simavr"}
            return "some virtual modules run " + " and ".join(names.get(p, p) for p in others)
        from .core import FleetCore

        return FleetCore.of(bus.clock, profile)

    def _core(self, bus: Bus, scenario: Scenario, mux_cut: bool) -> "FleetCore | None":
        core = self._core_or_refusal(bus, scenario, mux_cut, self.profile.name)
        return None if isinstance(core, str) else core

    def power_up(self, stagger: bool = True, *, freeze_gc: bool = False) -> None:
        """Switch the base on: every module boots, each timer at its own (seeded) phase.

        ``freeze_gc``: for large fleets. The modules, boards and subscriptions live for the
        whole run, so after one collection they are moved out of the cyclic garbage
        collector's reach (``gc.freeze``): its full collections otherwise rescan them all,
        over and over (1000 modules: twice the wall time). Process-wide; cyclic garbage made
        of frozen objects is only reclaimed after ``gc.unfreeze()``."""
        if freeze_gc:
            gc.collect()
            gc.freeze()
        self.world.start()
        if self.lag is not None:
            self.lag.start()
        rng = random.Random(self.scenario.seed)
        now = self.bus.clock.now_ns()
        for ident in self._virtual:
            offset = rng.randrange(TICK_NS) if stagger else 0
            if ident in self.modules:
                self.bus.clock.call_at(now + offset, self.modules[ident].power_up)
        for ident in sorted(self.twins):  # after the virtual ones: their phases stay the same
            offset = rng.randrange(TICK_NS) if stagger else 0
            self.bus.clock.call_at(now + offset, self.twins[ident].power_up)

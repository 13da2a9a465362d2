"""A fleet: the world, a virtual module for every virtual module of a scenario, and a twin
(:mod:`module_sim.twin`) for every real one."""

from __future__ import annotations

import gc
import random

from bus.keys import module_endpoint
from bus.scenario import Scenario
from bus.timing import TICK_NS
from bus.transport import Bus

from .module import VirtualModule
from .profiles import profile
from .shards import partition
from .world import World


class Fleet:
    def __init__(self, bus: Bus, scenario: Scenario, *, profile_name: str | None = None,
                 mux_cut: bool = False, shard: tuple[int, int] | None = None,
                 slack_ns: int = 0) -> None:
        """``shard=(k, n)``: only part ``k`` of ``n`` (:func:`module_sim.shards.partition`):
        its modules and its part of the world, for a fleet spread over processes on a
        lockstep clock; ``slack_ns`` how late light from other shards may arrive."""
        self.bus = bus
        self.scenario = scenario
        self.profile = profile(profile_name or scenario.profile)
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
        self.modules = {m.id: VirtualModule(bus, m.id, self.profile, ir_baud=scenario.ir_baud,
                                            mux_cut=mux_cut, program=scenario.program_of(m))
                        for m in scenario.modules if m.kind == "virtual" and m.id in mine}
        # every virtual module, for the power-up phases: a shard draws them all, in order
        self._virtual = sorted(m.id for m in scenario.modules if m.kind == "virtual")
        self.twins = {m.id: VirtualModule(bus, m.id, self.profile, ir_baud=scenario.ir_baud,
                                          mux_cut=mux_cut, origin="twin")
                      for m in scenario.modules if m.kind in ("real", "firmware")}

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
        rng = random.Random(self.scenario.seed)
        now = self.bus.clock.now_ns()
        for ident in self._virtual:
            offset = rng.randrange(TICK_NS) if stagger else 0
            if ident in self.modules:
                self.bus.clock.call_at(now + offset, self.modules[ident].power_up)
        for ident in sorted(self.twins):  # after the virtual ones: their phases stay the same
            offset = rng.randrange(TICK_NS) if stagger else 0
            self.bus.clock.call_at(now + offset, self.twins[ident].power_up)

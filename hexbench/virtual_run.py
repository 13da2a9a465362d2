"""A virtual run in one process: a scenario's fleet and the PC endpoint on a private bus with a
virtual clock, optionally recorded to MCAP.

This is the one place that says in which order the participants of an in-process virtual run
join the bus: recorder, run metadata, PC, world and modules, power-up — the order of
``hexbench run`` (hexbench/run.py), whose recordings can be compared too. The order matters for
determinism — samples published at one instant are handled in publish order and then
subscription order — so a bus replay with ``--compare`` (:mod:`hexbench.compare`) rebuilds a
run exactly like this and gets the same frames, byte for byte, at the same sim times.
"""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path
from typing import Any, Callable, Mapping

from bus.clock import VirtualClock
from bus.messages import RunMeta
from bus.scenario import Scenario, load
from bus.session import SessionOptions
from bus.transport import Bus
from module_sim.fleet import Fleet
from planner_svc.endpoint import PcEndpoint

from recordings.meta import package_versions
from recordings.recorder import Recorder
from recordings.stats import Tally

_private = itertools.count()


def scenario_ref(scenario: Scenario) -> str:
    """What a recording stores to find the scenario again: a built-in's name, a file's path."""
    src = scenario.source
    if src.startswith("<") or not src:
        return scenario.name
    return src


def resolve_scenario(ref: str, *, profile: str | None = None, seed: int | None = None) -> Scenario:
    """The scenario a recording names, with the profile and seed it ran with."""
    sc = load(ref)
    changes: dict[str, Any] = {}
    if profile:
        changes["profile"] = profile
    if seed is not None:
        changes["seed"] = int(seed)
    return dataclasses.replace(sc, **changes) if changes else sc


class VirtualRun:
    """A fleet, its world and the PC on a private virtual-clock bus.

    ``record`` (a path) attaches a :class:`Recorder` first, so it sees everything, and
    ``attach(bus)`` subscribes any other observer right after it; the run
    also publishes its :class:`RunMeta` on ``meta`` as ``hexbench run`` does.
    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, scenario: Scenario | str, *, fleet: str | None = None, record: str | Path | None = None,
                 argv: list[str] | None = None, pcs: tuple[str, ...] = ("pc",),
                 recorder_options: Mapping[str, Any] | None = None, stagger: bool = True,
                 attach: Callable[[Bus], Any] | None = None) -> None:
        self.scenario = load(scenario) if isinstance(scenario, str) else scenario
        self.clock = VirtualClock()
        self.bus = Bus(self.clock, fleet or f"vrun{next(_private)}", options=SessionOptions(isolated=True))
        self.meta = RunMeta(scenario=scenario_ref(self.scenario), profile=self.scenario.profile,
                            seed=self.scenario.seed, planner="none", clock="virtual",
                            argv=list(argv or []), versions=package_versions(), fleet=self.bus.keys.fleet)
        self.recorder: Recorder | None = None
        try:
            if record is not None:
                self.recorder = Recorder(record, fleet=self.bus.keys.fleet, meta=self.meta,
                                         argv=list(argv or []), **dict(recorder_options or {}))
                self.recorder.attach(self.bus)
            if attach is not None:  # an observer, subscribed where a recorder would be
                attach(self.bus)
            self.bus.put(self.bus.keys.meta, self.meta.to_json())
            self.pcs = {name: PcEndpoint(self.bus, name=name, baud=self.scenario.ir_baud) for name in pcs}
            self.fleet = Fleet(self.bus, self.scenario)
            self.fleet.power_up(stagger=stagger)
        except BaseException:
            self.close()
            raise

    @property
    def pc(self) -> PcEndpoint:
        """The PC endpoint (named ``pc``)."""
        return self.pcs["pc"]

    def boot(self, timeout_s: float = 30.0) -> None:
        """Run until every module has finished booting (its ``COMM. LISTENING`` banner)."""
        n = len(self.fleet.modules)
        seen = [0]

        def on_banner(r: Any) -> None:
            if r.frame.view.get("banner") == "COMM_LST":
                seen[0] += 1

        self.pc.listeners.append(on_banner)
        try:
            self.clock.run(until=lambda: seen[0] >= n, timeout_s=timeout_s)
        finally:
            self.pc.listeners.remove(on_banner)
        if seen[0] < n:
            raise TimeoutError(f"{seen[0]} of {n} modules booted")

    def close(self) -> Tally | None:
        """Close the recorder (writing its footer) and the bus; the recorder's counts."""
        tally = self.recorder.close() if self.recorder is not None else None
        self.bus.close()
        return tally

    def __enter__(self) -> "VirtualRun":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""The rig the world tests share: a virtual fleet and the PC on one private bus.

Each test file's ``Rig`` subclasses :class:`FleetRig`, subscribes to what it watches, then
calls :meth:`FleetRig.boot`.
"""

from __future__ import annotations

import itertools

from bus.clock import VirtualClock
from bus.scenario import Scenario
from bus.session import SessionOptions
from bus.timing import NS_PER_S
from bus.transport import Bus
from module_sim.fleet import Fleet
from planner_svc.endpoint import PcEndpoint

BOOTED_S = 9.0  # every module has printed COMM. LISTENING by then (docs/protocol.md)
_fleets = itertools.count()


class FleetRig:
    """A fleet of ``scenario`` and a PC endpoint on an isolated bus with a virtual clock;
    the bus's ``event/*`` reports collected in :attr:`bus_events`."""

    def __init__(self, name: str, scenario: Scenario, profile: str | None = None) -> None:
        self.clock = VirtualClock()
        self.bus = Bus(self.clock, f"{name}{next(_fleets)}", options=SessionOptions(isolated=True))
        self.scenario = scenario
        self.fleet = Fleet(self.bus, scenario, profile_name=profile)
        self.pc = PcEndpoint(self.bus)
        self.bus_events: list[dict] = []
        self.bus.subscribe_json(f"{self.bus.keys.root}/event/*",
                                lambda k, d: self.bus_events.append(d))

    def boot(self) -> None:
        """Power the fleet up and run until every module has booted."""
        self.fleet.power_up()
        self.run_to(BOOTED_S)

    def run_to(self, seconds: float) -> None:
        self.clock.run(until_ns=int(seconds * NS_PER_S))

    def run_for(self, seconds: float) -> None:
        self.run_to(self.clock.now_ns() / NS_PER_S + seconds)

    def close(self) -> None:
        self.bus.close()

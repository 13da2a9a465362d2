"""hexbench's pytest plugin (entry point ``pytest11``): wire-protocol tests against any target.

Options:

* ``--hexbench-target virtual`` (default): a virtual module on a private bus, virtual clock.
* ``--hexbench-target serial:<url>``: a real module behind a serial port (hardware-in-the-loop
  issue; not available yet: tests that need it are skipped with that reason).
* ``--hexbench-profile v2|thesis-2009|both`` (default both): the firmware profile(s).

Fixtures: ``hexbench_bench`` (a powered single-module bench: ``.pc``, ``.clock``, ``.module``
for virtual targets), ``pc`` (the bench's PC endpoint after the module finished booting).
The conformance suite for spec §5-§9 ships in ``module_sim.conformance``:
``pytest --pyargs module_sim.conformance --hexbench-target virtual``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Iterator

import pytest

_fleets = itertools.count()


def pytest_addoption(parser) -> None:
    group = parser.getgroup("hexbench")
    group.addoption("--hexbench-target", default="virtual",
                    help="what the conformance suite talks to: 'virtual' (default) or 'serial:<url>'")
    group.addoption("--hexbench-profile", default="both", choices=["v2", "thesis-2009", "both"],
                    help="firmware profile of the target (default: both, for virtual targets)")


def pytest_generate_tests(metafunc) -> None:
    if "hexbench_profile" in metafunc.fixturenames:
        opt = metafunc.config.getoption("--hexbench-profile")
        metafunc.parametrize("hexbench_profile", ["v2", "thesis-2009"] if opt == "both" else [opt])


@pytest.fixture
def hexbench_target(request) -> str:
    return request.config.getoption("--hexbench-target")


@dataclass
class Bench:
    """One module under test and the PC that talks to it."""

    target: str
    profile: str
    clock: object
    bus: object
    pc: object
    fleet: object | None = None
    module_id: int = 1
    booted: bool = False
    boot_frames: list = field(default_factory=list)

    @property
    def virtual(self) -> bool:
        return self.target == "virtual"

    @property
    def module(self):
        if not self.virtual:
            pytest.skip("port bits are only observable on a virtual target")
        return self.fleet.modules[self.module_id]

    def boot(self, timeout_s: float = 30.0):
        """Wait for the boot sequence to finish (the ``COMM. LISTENING`` banner)."""
        if not self.booted:
            self.pc.expect("banner", banner="COMM_LST", timeout_s=timeout_s, since=0)
            self.boot_frames = list(self.pc.received)
            self.booted = True
        return self.boot_frames


@pytest.fixture
def hexbench_bench(hexbench_target: str, hexbench_profile: str) -> Iterator[Bench]:
    from bus.clock import VirtualClock
    from bus.scenario import loads
    from bus.session import SessionOptions
    from bus.transport import Bus
    from planner_svc.endpoint import PcEndpoint

    from .fleet import Fleet

    if hexbench_target != "virtual":
        pytest.skip(f"target {hexbench_target!r}: serial targets arrive with the hardware-in-the-loop "
                    "bridge (hil); only 'virtual' is available")
    clock = VirtualClock()
    bus = Bus(clock, f"conformance{next(_fleets)}", options=SessionOptions(isolated=True))
    try:
        scenario = loads(f'profile = "{hexbench_profile}"\n[[modules]]\ncell = [0, 0]\nid = 1\n')
        fleet = Fleet(bus, scenario)
        pc = PcEndpoint(bus)
        fleet.power_up(stagger=False)
        yield Bench(hexbench_target, hexbench_profile, clock, bus, pc, fleet)
    finally:
        bus.close()


@pytest.fixture
def pc(hexbench_bench: Bench):
    hexbench_bench.boot()
    return hexbench_bench.pc

"""Benchmark: module-seconds emulated per wall second, virtual clock (issue: virtual module).

(a) booted and idle — idle boards wait on events, so this should be almost free;
(b) every module executing a stream of commands (broadcast by the PC).
Targets on one core: (a) >= 100 000, (b) >= 1 000. Run: pytest -s tests/benchmarks/test_module_bench.py
(``HEXBENCH_BENCH_SIZES=1,100,1000`` selects the fleet sizes).

Rates are module-seconds of virtual time per wall second (and per CPU second of the process, all
threads, which a busy shared machine disturbs less). The busy phase is measured after one warm-up
command (first use of each bus key declares its zenoh publisher) over at least 10 commands and
15 s of virtual time. Fleets are powered up with ``freeze_gc`` (see ``Fleet.power_up``).

A module's hardware id is its DIP switch byte (1..255), so one fleet holds at most 255 modules:
a larger benchmark runs several fleets (``--fleet`` namespaces, each with its own world and PC)
on one clock and one zenoh session, in one process — e.g. 1000 modules as 4 fleets of 250.
"""

import gc
import os
import time

import pytest

from bus.clock import VirtualClock
from bus.session import SessionOptions, open_session
from bus.timing import NS_PER_S
from bus.transport import Bus
from module_sim.fleet import Fleet
from planner_svc.endpoint import PcEndpoint
from tests.support.block_fleets import block_scenarios, fleet_names

SIZES = [int(s) for s in os.environ.get("HEXBENCH_BENCH_SIZES", "1,100,1000").split(",")]


def _fleets(n: int, tag: str, program: str = "model"):
    """``n`` modules as ceil(n / 255) fleets on one virtual clock and one zenoh session;
    ``program``: the Python programs ("model") or the C firmware ("firmware")."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    buses, fleets, pcs = [], [], []
    for name, sc in zip(fleet_names(n, tag), block_scenarios(n, program)):
        bus = Bus(clock, name, session=session)
        fleets.append(Fleet(bus, sc))
        buses.append(bus)
        pcs.append(PcEndpoint(bus))
    return clock, session, buses, fleets, pcs


@pytest.mark.parametrize("n", SIZES)
def test_idle_and_busy(n):
    clock, session, buses, fleets, pcs = _fleets(n, "a")
    try:
        t = time.perf_counter()
        for i, fleet in enumerate(fleets):
            fleet.power_up(freeze_gc=i == len(fleets) - 1)
        clock.run(until_ns=9 * NS_PER_S)  # every module has booted by then
        boot_wall = time.perf_counter() - t
        t = time.perf_counter()
        idle_s = 1000.0
        clock.run(until_ns=clock.now_ns() + int(idle_s * NS_PER_S))
        idle_wall = time.perf_counter() - t
        rate_idle = n * idle_s / max(idle_wall, 1e-9)

        def command(k: int) -> None:
            for pc in pcs:
                pc.send("SxP" if k % 2 == 0 else "SxOff", 1 + k % 6)
            clock.run(until_ns=clock.now_ns() + 1_500_000_000)  # frame, relay, echo, ACKs

        command(1)  # warm-up
        start_ns = clock.now_ns()
        t, cpu = time.perf_counter(), time.process_time()
        rounds = 10 if n >= 100 else 100  # a single module needs more rounds to be timed
        for k in range(rounds):
            command(k)
        busy_wall = time.perf_counter() - t
        busy_cpu = time.process_time() - cpu
        busy_s = (clock.now_ns() - start_ns) / NS_PER_S
        rate_busy = n * busy_s / busy_wall
        rate_cpu = n * busy_s / busy_cpu
        executed = sum(m.ctrl.executed_total for f in fleets for m in f.modules.values())
        print(f"\n[module bench] n={n} ({len(fleets)} fleet(s)): boot {boot_wall:.2f} s wall for 9 s sim; "
              f"(a) idle {rate_idle:,.0f} module-s/s (target >= 100,000); "
              f"(b) busy {rate_busy:,.0f} module-s/s ({rate_cpu:,.0f} per CPU s) over {busy_s:.1f} s sim, "
              f"{executed} control commands executed (target >= 1,000)")
        assert executed == n * (rounds + 1)  # every module executed every command
    finally:
        for bus in buses:
            bus.close()
        session.close()
        gc.unfreeze()

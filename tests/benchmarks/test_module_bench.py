"""Benchmark: module-seconds emulated per wall second, virtual clock (issue: virtual module).

(a) booted and idle — idle boards wait on events, so this should be almost free;
(b) every module executing a stream of commands (broadcast by the PC).
Targets on one core: (a) >= 100 000, (b) >= 1 000. Run: pytest -s tests/benchmarks/test_module_bench.py
"""

import os
import time

import pytest

from bus.clock import VirtualClock
from bus.scenario import loads
from bus.session import SessionOptions
from bus.timing import NS_PER_S
from bus.transport import Bus
from module_sim.fleet import Fleet
from planner_svc.endpoint import PcEndpoint

SIZES = [int(s) for s in os.environ.get("HEXBENCH_BENCH_SIZES", "1,100,1000").split(",")]


def _fleet(n: int, tag: str):
    clock = VirtualClock()
    bus = Bus(clock, f"bench{tag}{n}", options=SessionOptions(isolated=True))
    side = int(n ** 0.5) + 1
    cells = "\n".join(f"[[modules]]\ncell = [{k % side}, {k // side}]\nid = {k + 1}" for k in range(n))
    fleet = Fleet(bus, loads(f'profile = "v2"\nfixed = [0, 0]\n{cells}\n'))
    return clock, bus, fleet, PcEndpoint(bus)


@pytest.mark.parametrize("n", SIZES)
def test_idle_and_busy(n):
    clock, bus, fleet, pc = _fleet(n, "a")
    try:
        t = time.perf_counter()
        fleet.power_up()
        clock.run(until_ns=9 * NS_PER_S)  # every module has booted by then
        boot_wall = time.perf_counter() - t
        t = time.perf_counter()
        idle_s = 1000.0
        clock.run(until_ns=clock.now_ns() + int(idle_s * NS_PER_S))
        idle_wall = time.perf_counter() - t
        rate_idle = n * idle_s / max(idle_wall, 1e-9)

        start_ns = clock.now_ns()
        t = time.perf_counter()
        rounds = 10
        for k in range(rounds):
            pc.send("SxP" if k % 2 == 0 else "SxOff", 1 + k % 6)
            clock.run(until_ns=clock.now_ns() + 1_500_000_000)  # frame, relay, echo, ACKs
        busy_wall = time.perf_counter() - t
        busy_s = (clock.now_ns() - start_ns) / NS_PER_S
        rate_busy = n * busy_s / busy_wall
        executed = sum(len(m.ctrl.executed) for m in fleet.modules.values())
        print(f"\n[module bench] n={n}: boot {boot_wall:.2f} s wall for 9 s sim; "
              f"(a) idle {rate_idle:,.0f} module-s/s (target >= 100,000); "
              f"(b) busy {rate_busy:,.0f} module-s/s over {busy_s:.1f} s sim, "
              f"{executed} control commands executed (target >= 1,000)")
        assert executed == n * rounds  # every module executed every command
    finally:
        bus.close()

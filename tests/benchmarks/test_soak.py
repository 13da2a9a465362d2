"""Soak benchmark (issue: hardening): 200 000 command/ACK round trips on the virtual clock
against one module of a fleet with its world; RSS after warm-up must grow by less than
10 MB. Run alone: ``pytest -s tests/benchmarks/test_soak.py`` (``HEXBENCH_SOAK_N`` scales
it; ``HEXBENCH_SOAK_PROGRAM=firmware`` runs the C firmware as the module's program)."""

from __future__ import annotations

import gc
import os
import time

ROUND_TRIPS = int(os.environ.get("HEXBENCH_SOAK_N", "200000"))
PROGRAM = os.environ.get("HEXBENCH_SOAK_PROGRAM", "model")
WARM_UP = min(10_000, ROUND_TRIPS // 10)
GROWTH_LIMIT_MB = 10.0


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_round_trips_keep_memory_flat():
    from bus.clock import VirtualClock
    from bus.scenario import loads
    from bus.session import SessionOptions
    from bus.transport import Bus
    from module_sim.fleet import Fleet
    from planner_svc.endpoint import PcEndpoint

    bus = Bus(VirtualClock(), "soak", options=SessionOptions(isolated=True))
    try:
        fleet = Fleet(bus, loads(f'profile = "v2"\nprogram = "{PROGRAM}"\nfixed = [0, 0]\n'
                                 "[[modules]]\ncell = [0, 0]\nid = 1\n"))
        pc = PcEndpoint(bus)
        fleet.power_up(stagger=False)
        pc.expect("banner", banner="COMM_LST", timeout_s=30, since=0)
        t = time.perf_counter()
        base = None
        samples = []
        for k in range(ROUND_TRIPS):
            pc.ack("JxOpen" if k % 2 == 0 else "JxClose", 1 + k % 6, timeout_s=5)
            if k + 1 == WARM_UP:
                gc.collect()
                base = _rss_mb()
            if base is not None and (k + 1) % (ROUND_TRIPS // 10) == 0:
                gc.collect()
                samples.append(round(_rss_mb() - base, 1))
        wall = time.perf_counter() - t
        growth = samples[-1] if samples else 0.0
        print(f"\n[soak] {PROGRAM}: {ROUND_TRIPS} round trips ({bus.clock.now_ns() / 1e9:.0f} s of sim "
              f"time) in {wall:.0f} s; RSS after warm-up {base:.0f} MB, growth per tenth {samples} MB; "
              f"{'met' if growth < GROWTH_LIMIT_MB else 'MISSED'}: growth < {GROWTH_LIMIT_MB:g} MB")
        assert growth < GROWTH_LIMIT_MB
    finally:
        bus.close()

"""The benchmarks' fleets: ``n`` modules as ceil(n / 255) square blocks (the hardware ids
are 1..255), one scenario each, and a shard process that runs part of them on a lockstep
clock (``python -m tests.support.block_fleets ...``, for the sharded fleet-scale row)."""

from __future__ import annotations

import argparse
import math
import sys

from bus.scenario import Scenario, loads

MAX_IDS = 255  # hardware ids 1..255 (the DIP switches)


def block_scenarios(n: int, program: str = "model") -> list[Scenario]:
    """Fleet ``i`` has seed ``i``: its modules power up at their own phases, so the fleets' coil
    changes and banners do not fall on the same instants (shared seeds flattered a clock with
    several fleets: their events shared windows)."""
    k = math.ceil(n / MAX_IDS)
    sizes = [n // k + (1 if i < n % k else 0) for i in range(k)]
    out = []
    for i, size in enumerate(sizes):
        side = int(size ** 0.5) + 1
        cells = "\n".join(f"[[modules]]\ncell = [{j % side}, {j // side}]\nid = {j + 1}" for j in range(size))
        out.append(loads(f'profile = "v2"\nprogram = "{program}"\nseed = {i}\nfixed = [0, 0]\n{cells}\n'))
    return out


def fleet_names(n: int, tag: str) -> list[str]:
    return [f"bench{tag}{n}x{i}" for i in range(math.ceil(n / MAX_IDS))]


def main(argv: list[str] | None = None) -> int:
    """One shard of every block fleet, on one lockstep clock with the benchmark's process."""
    from bus.lockstep import Lockstep, LockstepClock
    from bus.session import SessionOptions, open_session
    from bus.transport import Bus
    from module_sim.fleet import Fleet
    from module_sim.shards import LAGS, participants, shard_name, window_ns

    p = argparse.ArgumentParser()
    p.add_argument("n", type=int)
    p.add_argument("tag")
    p.add_argument("shard", help="K/N")
    p.add_argument("--connect", required=True)
    p.add_argument("--program", default="model")
    args = p.parse_args(argv)
    k, parts = (int(v) for v in args.shard.split("/"))
    clock = LockstepClock()
    session = open_session(SessionOptions(connect=[args.connect]))
    scenarios = block_scenarios(args.n, args.program)
    buses = [Bus(clock, name, session=session) for name in fleet_names(args.n, args.tag)]
    w = window_ns(scenarios[0].ir_baud)
    fleets = [Fleet(bus, sc, shard=(k, parts), slack_ns=2 * w) for bus, sc in zip(buses, scenarios)]
    step = Lockstep(buses[0], shard_name(k), participants(parts), w, timeout_s=300, lags=LAGS)
    for i, fleet in enumerate(fleets):
        fleet.power_up(freeze_gc=i == len(fleets) - 1)
    print("ready", flush=True)
    try:
        clock.run()
        print(f"published {sum(b.published for b in buses)}", flush=True)
    finally:
        step.close()
        for bus in buses:
            bus.close()
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

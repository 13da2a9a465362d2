"""What the IR medium costs in a boot pile-up at the PC (module_sim/air.py, module_sim/core
core.c): every module's banner reaches the PC's receiver within one tick of the others, so
each byte meets hundreds of carriers in flight. Prints the Python medium's cost per byte and
the fleet core's C time (inside core_run) over a 250-module boot; docs/benchmarks.md quotes
them. Timings on the shared 2-core machine are noisy: read the median of 3."""

from __future__ import annotations

import random
import statistics
import time

from bus.clock import VirtualClock
from bus.session import SessionOptions, open_session
from bus.timing import NS_PER_S, TICK_NS, byte_time_ns
from bus.transport import Bus
from module_sim.air import Air
from module_sim.fleet import Fleet
from tests.support.block_fleets import block_scenarios

TB = byte_time_ns(300)


def _python_pile_up(transmitters: int, length: int) -> tuple[float, int]:
    """Seconds for one Air to take ``transmitters`` banners of ``length`` bytes, each starting
    within one tick, bytes back to back; and the garbled bytes."""
    rnd = random.Random(0)
    bursts = [(f"m{n}.comm", bytes(rnd.randrange(256) for _ in range(length)), rnd.randrange(TICK_NS))
              for n in range(transmitters)]
    bursts.sort(key=lambda b: b[2])
    air = Air()
    garbled = 0
    t0 = time.perf_counter()
    for src, data, t in bursts:
        starts = [t + k * TB for k in range(length)]
        values, corrupt, _fixes, _sources = air.collide(src, 0, data, starts, TB, t)
        air.add(src, 0, data, values, corrupt, starts, TB)
        garbled += sum(corrupt)
    return time.perf_counter() - t0, garbled


def _core_boot(modules: int, seconds: float) -> tuple[float, int, int]:
    """C seconds inside core_run, windows and collisions of one fleet's boot on the core."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, "mediumbench", session=session)
    try:
        fleet = Fleet(bus, block_scenarios(modules, "firmware")[0], core=True)
        fleet.power_up()
        clock.run(until_ns=int(seconds * NS_PER_S))
        return fleet.core.run_ns / 1e9, fleet.core.windows, fleet.world.collisions
    finally:
        bus.close()
        session.close()


def test_the_medium_in_a_boot_pile_up():
    py = [_python_pile_up(250, 32) for _ in range(3)]
    py_s = statistics.median(s for s, _ in py)
    print(f"\nPython medium (Air), 250 banners of 32 bytes within one tick at one receiver: "
          f"{py_s * 1e3:.0f} ms, {py_s / (250 * 32) * 1e6:.1f} us a byte ({py[0][1]} bytes garbled)")
    core = [_core_boot(250, 4.0) for _ in range(3)]
    c_s = statistics.median(s for s, _, _ in core)
    print(f"fleet core, 250-module boot to 4 s: {c_s * 1e3:.0f} ms inside core_run "
          f"(runs {', '.join(f'{s * 1e3:.0f}' for s, _, _ in core)} ms), {core[0][1]} windows, "
          f"{core[0][2]} collisions")
    assert py[0][1] > 250 * 16  # the pile-up is there: most bytes meet others
    assert core[0][2] > 100

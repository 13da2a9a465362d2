"""Fuzzed ``ir/tx`` samples into the fleet core, for its AddressSanitizer build
(tests/world/test_core_asan.py runs this under ``LD_PRELOAD`` of libasan).

``python tests/support/core_fuzz.py LIB [--examples N]`` loads the core from ``LIB``, runs a
two-module firmware fleet on it and feeds its world hypothesis-made bursts: well formed, too
long for a board, with start times, corrupt flags and byte times that disagree with the
bytes or do not fit. Each one is taken or refused with ValueError (a ``bad-sample`` event
when it comes from elsewhere); the core then runs on. At the end the fleet leaves the core
with light still in the air to it. The same lengths go straight to C too
(``core_put_light`` must refuse what Python would have). Prints one line of counts.

``--canary``: hand C a ``starts`` shorter than the length it is told (the bug this guards):
the sanitizer must report it, or the target proves nothing.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import sys
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

BYTE_NS = 4_166_667

sources = st.sampled_from(["pc", "x1", "m1.comm", "m2.comm", "m9.comm"])
times = st.one_of(st.integers(-2, 2**64 + 1), st.integers(0, 4 * 10**9), st.floats(allow_nan=False))


@st.composite
def bursts(draw: st.DrawFn) -> dict:
    """An ``ir/tx`` burst sample's dict, mostly well formed around ``now`` (0 here: the run
    adds it), with one field at a time made wrong."""
    data = draw(st.binary(max_size=draw(st.sampled_from([4, 40, 600]))))
    byte_ns = draw(st.one_of(st.just(BYTE_NS), st.integers(-1, 2**33)))
    gap = draw(st.integers(0, 2 * BYTE_NS))
    starts: object = [i * gap for i in range(len(data))]
    n_starts = draw(st.one_of(st.just(len(data)), st.integers(0, len(data) + 3)))
    if n_starts != len(data) or draw(st.booleans()):
        starts = draw(st.lists(times, min_size=n_starts, max_size=n_starts))
    corrupt = draw(st.one_of(st.just([]), st.lists(st.booleans(), min_size=len(data), max_size=len(data)),
                             st.lists(st.booleans(), max_size=len(data) + 3)))
    return {"src": draw(sources), "burst": draw(st.integers(0, 9)), "transceiver": draw(st.integers(0, 6)),
            "data": data.hex(), "starts": starts, "byte_ns": byte_ns, "corrupt": corrupt, "type": "burst"}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("lib", type=Path, help="the libhexcore.so to load (its ASan build)")
    p.add_argument("--examples", type=int, default=300)
    p.add_argument("--canary", action="store_true")
    args = p.parse_args(argv)

    import module_sim.core as core_mod

    core_mod.LIB = args.lib.resolve()  # the core the fleet loads (built by the caller)
    from block_fleets import block_scenarios

    from bus import SessionOptions, VirtualClock
    from bus.transport import Bus
    from module_sim.fleet import Fleet

    clock = VirtualClock()
    bus = Bus(clock, "corefuzz", options=SessionOptions(isolated=True))
    fleet = Fleet(bus, block_scenarios(2, "firmware")[0])
    core = fleet.core
    assert core is not None and Path(core.lib._name) == core_mod.LIB, core and core.lib._name
    fleet.power_up()
    clock.run(until_ns=10**9)
    lib, h = core.lib, core._h
    src = core._source(core._fleets[id(fleet.world)], "fuzz")  # named: its collisions are events
    rcv = (ctypes.c_int32 * 2)(lib.core_receiver(h, 0, 0), lib.core_receiver(h, 1, 0))

    if args.canary:  # C told 2001 starts, given 2000: only the sanitizer can see it
        starts = np.arange(2000, dtype=np.uint64) * BYTE_NS + clock.now_ns()
        lib.core_put_light(h, clock.now_ns(), src, 2, ctypes.addressof(rcv), bytes(2001), 2001,
                           starts.ctypes.data, 2001, BYTE_NS, None, 0)
        print("canary not caught")
        return 0

    counts = {"taken": 0, "refused": 0, "c-refused": 0}

    @settings(max_examples=args.examples, database=None, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(d=bursts(), run_ns=st.integers(0, 60_000_000), n_c=st.integers(0, 700), claim=st.integers(0, 700))
    def feed(d: dict, run_ns: int, n_c: int, claim: int) -> None:
        now = clock.now_ns()
        if isinstance(d["starts"], list) and all(type(s) is int for s in d["starts"]):
            d["starts"] = [s + now if 0 <= s < 2**40 else s for s in d["starts"]]
        try:
            fleet.world._on_ir(f"hexbot/corefuzz/ir/tx/{d['src']}", json.dumps(d).encode())
            counts["taken"] += 1
        except ValueError:
            counts["refused"] += 1  # from elsewhere: a bad-sample event
        # C alone, told the truth about lengths that disagree
        data, starts = bytes(n_c), np.arange(claim, dtype=np.uint64) * BYTE_NS + now
        flags = bytes(claim)
        refused = lib.core_put_light(h, now, src, 2, ctypes.addressof(rcv), data, n_c, starts.ctypes.data,
                                     claim, BYTE_NS, flags, claim)
        assert (refused != 0) == (claim != n_c), (refused, claim, n_c)
        counts["c-refused"] += refused != 0
        if not refused:
            core._after_call()  # what put_light does after the core took light
        clock.run(until_ns=now + run_ns)
        assert clock.error is None, clock.error

    feed()
    # the fleet leaves the core with light still in the air to it; the core runs on
    windows = core.windows
    fleet.world._on_ir("hexbot/corefuzz/ir/tx/pc", json.dumps(
        {"src": "pc", "burst": 99, "transceiver": 0, "data": "55" * 40, "type": "burst", "byte_ns": BYTE_NS,
         "starts": [clock.now_ns() + i * BYTE_NS for i in range(40)]}).encode())
    core.remove_fleet(fleet.world)
    core._after_call()
    clock.run(until_ns=clock.now_ns() + 10**9)
    assert clock.error is None and core.windows > windows, (clock.error, core.windows)
    bus.close()
    print(" ".join(f"{k} {v}" for k, v in counts.items()), f"windows {core.windows}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A toy lockstep participant: a ticker that messages its peer with lookahead.

Participants ``a`` and ``b`` tick with their own periods and phases; every third tick sends
the other a message to act on ``LOOKAHEAD_NS`` later, and every even message is answered
the same way. Each logs its ticks and acts. Over one process (:func:`one_process`) or one
process each (``python -m tests.support.lockstep_toy NAME ...``, on a lockstep clock) the
logs must be the same.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import sys
import time
from typing import Any

from bus import SessionOptions, VirtualClock
from bus.transport import Bus

WINDOW_NS = 20_000_000
LOOKAHEAD_NS = 45_000_000  # > one window: a message is handled at most one window late
PERIOD_NS = {"a": 7_000_000, "b": 11_000_000}
PHASE_NS = {"a": 3_000_001, "b": 5_000_003}
UNTIL_NS = 2_000_000_000


def build(bus: Bus, me: str, other: str, log: list[list[Any]]) -> None:
    clock = bus.clock
    ticks = itertools.count()

    def tick() -> None:
        i = next(ticks)
        log.append([clock.now_ns(), me, "tick", i])
        if i % 3 == 0:
            bus.put_json(f"{bus.keys.root}/toy/{other}",
                         {"from": me, "i": i, "act_at": clock.now_ns() + LOOKAHEAD_NS})
        clock.call_later(PERIOD_NS[me], tick)

    def act(msg: dict[str, Any]) -> None:
        log.append([clock.now_ns(), me, "act", msg["from"], msg["i"]])
        if msg["i"] % 2 == 0:
            bus.put_json(f"{bus.keys.root}/toy/{other}",
                         {"from": me, "i": msg["i"] * 1000 + 1, "act_at": clock.now_ns() + LOOKAHEAD_NS})

    # the handler acts on the time the message carries, not on when it is handled
    bus.subscribe_json(f"{bus.keys.root}/toy/{me}", lambda k, msg: clock.call_at(msg["act_at"], act, msg))
    clock.call_at(PHASE_NS[me], tick)


def one_process(fleet: str) -> list[list[Any]]:
    """Both participants on one virtual clock in one process: the reference."""
    clock = VirtualClock()
    a = Bus(clock, fleet, options=SessionOptions(isolated=True))
    b = Bus(clock, fleet, session=a.session)
    log: list[list[Any]] = []
    try:
        build(a, "a", "b", log)
        build(b, "b", "a", log)
        clock.run(until_ns=UNTIL_NS - 1)
    finally:
        b.close()
        a.close()
    return log


def main(argv: list[str] | None = None) -> int:
    from bus.lockstep import Lockstep, LockstepClock, PeerLost

    p = argparse.ArgumentParser()
    p.add_argument("name", choices=["a", "b"])
    p.add_argument("--fleet", required=True)
    p.add_argument("--listen", action="append", default=[])
    p.add_argument("--connect", action="append", default=[])
    p.add_argument("--mode", default="peer")
    p.add_argument("--out", required=True)
    p.add_argument("--die-in-window", type=int, help="kill this process (SIGKILL) in window K")
    p.add_argument("--window-ns", type=int, default=WINDOW_NS)
    p.add_argument("--idle", action="store_true", help="no ticks, no messages: the barrier alone")
    args = p.parse_args(argv)
    me, other = args.name, "b" if args.name == "a" else "a"
    clock = LockstepClock()
    bus = Bus(clock, args.fleet, options=SessionOptions(mode=args.mode, listen=args.listen,
                                                        connect=args.connect))
    log: list[list[Any]] = []
    if args.idle:
        bus.subscribe(f"{bus.keys.root}/toy/{me}", lambda k, p: None)  # samples arrive through it
    else:
        build(bus, me, other, log)
    if args.die_in_window is not None:
        clock.call_at(args.die_in_window * WINDOW_NS + WINDOW_NS // 2,
                      lambda: os.kill(os.getpid(), signal.SIGKILL))
    step = Lockstep(bus, me, ["a", "b"], args.window_ns, timeout_s=30)
    print("ready", flush=True)
    try:
        step.wait_for_peers()
        t0 = time.perf_counter()
        step.run(until_ns=UNTIL_NS)
        print(f"windows {step.window} in {time.perf_counter() - t0:.3f} s", flush=True)
    except PeerLost as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 3
    finally:
        with open(args.out, "w") as f:
            json.dump({"log": log, "windows": step.window, "released": step.released}, f)
        step.close()
        bus.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A hostile or broken sample from another process harms nobody (issue: hardening): the
participant whose handler cannot take it publishes a ``bad-sample`` event and goes on."""

from __future__ import annotations

import os

from bus import SessionOptions, WallClock
from bus.transport import Bus
from planner_svc.endpoint import ExpectTimeout, PcEndpoint
from processes import free_port, hexbench, wall_fleet

#: (key under the fleet, payload): each broke a participant before (issue 31's probes)
BAD = [
    ("world/inject", b"not json"),
    ("ir/tx/m1.comm", b"{}"),
    ("world/actuators/m1", b"[1,2]"),
    ("world/confirm", b'{"type":"pose"}'),
    ("world/switches/m1", b"null"),
]


def _talk_to_m1(pc: PcEndpoint) -> None:
    """Select m1 alone (the two modules' answers to a broadcast collide), retrying while
    the fleet boots: its modules answer from about 7.5 s after power-up."""
    for _ in range(20):
        mark = len(pc.received)
        pc.send("Select", 1, 1, 0)
        try:
            pc.expect("ack", since=mark, timeout_s=2.0, byte=60)
            return
        except ExpectTimeout:
            continue
    raise AssertionError(f"the fleet never answered: {[r.frame.describe() for r in pc.received]}")


def test_a_fleet_survives_bad_samples_and_says_so():
    port = free_port()
    fleet = f"bad{os.getpid()}"
    proc = wall_fleet("pair", port, fleet)
    clock = WallClock()
    bus = Bus(clock, fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        events: list[dict] = []
        bus.subscribe_json(f"{bus.keys.root}/event/*",
                           lambda k, d: events.append(d) if d["kind"] == "bad-sample" else None)
        pc = PcEndpoint(bus)
        _talk_to_m1(pc)  # the fleet is up and hears this process
        for key, payload in BAD:
            bus.put(f"{bus.keys.root}/{key}", payload)
        clock.run(until=lambda: len(events) >= len(BAD), timeout_s=20)
        assert sorted(e["key"] for e in events) == sorted(k for k, _ in BAD)
        assert all(e["reason"] and e["bytes"] for e in events)
        # still alive, still answering the PC
        assert pc.ack("SxP", 3, timeout_s=10).frame.view["byte"] == 11
        assert proc.poll() is None
    finally:
        bus.close()
        proc.terminate()
        proc.communicate(timeout=30)


def _malformed(rng, n: int) -> list[bytes]:
    """``n`` samples no handler may take: random bytes, cut JSON, JSON that is not an object,
    objects with a field missing or of the wrong type."""
    import json

    shapes = [
        lambda: rng.randbytes(rng.randrange(0, 40)),
        lambda: json.dumps({"src": "x", "data": "00"})[: rng.randrange(1, 20)].encode(),
        lambda: json.dumps(rng.choice([None, 1, -3.5, "burst", [1, 2], [], True])).encode(),
        lambda: json.dumps({rng.choice(["a", "zz", "type"]): rng.randrange(9)}).encode(),
        lambda: json.dumps({"type": "burst", "src": 5, "burst": "x", "data": 7}).encode(),
        lambda: json.dumps({"present": rng.choice([None, 3, "yes", [1, "x", {}]])}).encode(),
        lambda: json.dumps({"module": 7, "joints_open": "no", "magnets": None}).encode(),
    ]
    return [rng.choice(shapes)() for _ in range(n)]


def test_a_fleet_and_a_bridge_take_a_thousand_malformed_samples_per_key():
    """1 000 malformed samples on every key the fleet's and a hil bridge's handlers listen
    on: one ``bad-sample`` event each, and both still answer a PC."""
    import random

    port = free_port()
    fleet = f"fuzz{os.getpid()}"
    procs = [wall_fleet("pair", port, fleet, seconds=120),
             hexbench("hil", "--port", "loop://", "--clock", "wall", "--fleet", fleet,
                      "--seconds", "120", "--connect", f"tcp/127.0.0.1:{port}")]
    clock = WallClock()
    bus = Bus(clock, fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        procs[1].stdout.readline()
        events: list[dict] = []
        bus.subscribe_json(f"{bus.keys.root}/event/*",
                           lambda k, d: events.append(d) if d["kind"] == "bad-sample" else None)
        pc = PcEndpoint(bus)
        _talk_to_m1(pc)
        keys = ["world/inject", "world/confirm", "world/actuators/m1", "world/switches/m1",
                "ir/tx/m2.comm", "ir/rx/m1", "ir/tx/pc"]
        rng = random.Random(31)
        sent: dict[str, int] = {}
        for key in keys:
            for payload in _malformed(rng, 1000):
                bus.put(f"{bus.keys.root}/{key}", payload)
                sent[key] = sent.get(key, 0) + 1
        expect = {"ir/tx/pc": 2}  # the world's IR medium and the bridge both listen there
        total = sum(n * expect.get(k, 1) for k, n in sent.items())
        clock.run(until=lambda: len(events) >= total, timeout_s=60)
        got: dict[str, int] = {}
        for e in events:
            got[e["key"]] = got.get(e["key"], 0) + 1
        assert got == {k: n * expect.get(k, 1) for k, n in sent.items()}
        assert pc.ack("SxP", 3, timeout_s=10).frame.view["byte"] == 11
        assert all(p.poll() is None for p in procs)
    finally:
        bus.close()
        for p in procs:
            p.terminate()
            p.communicate(timeout=30)

"""A hostile or broken sample from another process harms nobody (issue: hardening): the
participant whose handler cannot take it publishes a ``bad-sample`` event and goes on."""

from __future__ import annotations

import os
import subprocess
import sys

from bus import SessionOptions, WallClock
from bus.transport import Bus
from planner_svc.endpoint import ExpectTimeout, PcEndpoint

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
    port = 19000 + os.getpid() % 1000
    fleet = f"bad{os.getpid()}"
    proc = subprocess.Popen([sys.executable, "-m", "hexbench", "fleet", "pair", "--clock", "wall",
                             "--listen", f"tcp/127.0.0.1:{port}", "--fleet", fleet, "--seconds", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    clock = WallClock()
    bus = Bus(clock, fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        assert proc.stdout.readline().startswith(f"fleet pair:")
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

"""The two clocks and the zenoh bus: determinism, delivery barrier, session discovery."""

import subprocess
import sys
import textwrap

from bus.clock import VirtualClock, WallClock
from bus.session import SessionOptions
from bus.transport import Bus


def _ping_pong(fleet: str) -> list[tuple[int, str, bytes]]:
    clock = VirtualClock()
    bus = Bus(clock, fleet, options=SessionOptions(isolated=True))
    log: list[tuple[int, str, bytes]] = []
    try:
        def a(key, payload):
            log.append((clock.now_ns(), "a", payload))
            if clock.now_ns() < 50_000:
                clock.call_later(1_000, bus.put, f"hexbot/{fleet}/b", payload + b"+")
                clock.call_later(1_000, bus.put, f"hexbot/{fleet}/c", b"side")

        def b(key, payload):
            log.append((clock.now_ns(), "b", payload))
            clock.call_later(3_000, bus.put, f"hexbot/{fleet}/a", payload)

        bus.subscribe(f"hexbot/{fleet}/a", a)
        bus.subscribe(f"hexbot/{fleet}/b", b)
        bus.subscribe(f"hexbot/{fleet}/*", lambda k, p: log.append((clock.now_ns(), "all", p)))
        clock.call_at(100, bus.put, f"hexbot/{fleet}/a", b"x")
        clock.run()
    finally:
        bus.close()
    return log


def test_virtual_clock_is_deterministic_through_zenoh():
    one, two = _ping_pong("det1"), _ping_pong("det2")
    assert one == two
    assert one[0] == (100, "a", b"x")
    # every sample reached every matching subscriber, in publish order, at its sim time
    assert [e for e in one if e[1] == "b"][0] == (1100, "b", b"x+")
    assert sum(1 for e in one if e[1] == "all") == sum(1 for e in one if e[1] != "all") + \
        sum(1 for e in one if e[1] == "all" and e[2] == b"side")


def test_virtual_time_jumps_and_until():
    clock = VirtualClock()
    seen = []
    clock.call_at(5_000_000_000, seen.append, "late")
    clock.call_at(10, seen.append, "early")
    clock.run(until_ns=1_000)
    assert seen == ["early"] and clock.now_ns() == 1_000
    clock.run()
    assert seen == ["early", "late"] and clock.now_ns() == 5_000_000_000


def test_cancelled_timer_does_not_fire():
    clock = VirtualClock()
    seen = []
    t = clock.call_at(10, seen.append, 1)
    t.cancel()
    clock.run()
    assert seen == []


def test_wall_clock_runs_posted_work_and_timers():
    clock = WallClock()
    seen = []
    clock.call_later(20_000_000, seen.append, "timer")
    clock.post(seen.append, "post")
    clock.run(until=lambda: len(seen) == 2, timeout_s=5)
    assert seen == ["post", "timer"] and clock.now_ns() >= 20_000_000


def test_a_late_timer_on_the_wall_clock_knows_when_it_was_due():
    """A timer held up by a slow one runs late: ``due_ns`` is still its due time (what a
    module stamps its actuator changes with), ``now_ns`` the real time; work posted from
    elsewhere is due when it runs."""
    import time

    clock = WallClock()
    t0 = clock.now_ns()
    seen = []

    def slow() -> None:
        end = time.monotonic() + 0.02
        while time.monotonic() < end:  # holds the clock thread, as a loaded machine does
            pass

    clock.call_at(t0 + 1_000_000, slow)
    clock.call_at(t0 + 2_000_000, lambda: seen.append((clock.due_ns(), clock.now_ns())))
    clock.run(until=lambda: bool(seen), timeout_s=5)
    due, now = seen[0]
    assert due == t0 + 2_000_000 and now >= t0 + 20_000_000
    clock.post(lambda: seen.append((clock.due_ns(), clock.now_ns())))
    clock.run(until=lambda: len(seen) == 2, timeout_s=5)
    assert seen[1][0] >= now


def test_wall_clock_drain_handles_every_local_sample_published_so_far():
    """zenoh calls each subscriber on its own thread: a subscriber to everything (a recorder)
    can lag behind one to a single key. ``drain`` waits for it; a timer is not run."""
    clock = WallClock()
    bus = Bus(clock, "drain", options=SessionOptions(isolated=True))
    try:
        everything, last = [], []
        bus.subscribe(bus.keys.all, lambda k, p: everything.append(p))
        bus.subscribe(bus.keys.root + "/x/last", lambda k, p: last.append(p))
        fired = []
        clock.call_later(10**12, fired.append, "timer")
        # a handler that publishes again: drain handles that sample too
        bus.subscribe(bus.keys.root + "/x/echo", lambda k, p: bus.put(bus.keys.root + "/x/last", p))
        for i in range(3000):
            bus.put(f"{bus.keys.root}/x/{i % 7}", str(i).encode())
        bus.put(bus.keys.root + "/x/echo", b"end")
        assert clock.drain(timeout_s=20)
        assert len(everything) == 3002 and everything[-1] == b"end"
        assert last == [b"end"] and not fired
    finally:
        bus.close()


def test_two_processes_with_default_options_find_each_other(tmp_path):
    """The default session: the first process listens on the well-known loopback endpoint,
    the second connects to it."""
    listener = textwrap.dedent("""
        import sys
        from bus.clock import WallClock
        from bus.transport import Bus
        clock = WallClock(); bus = Bus(clock, "disc")
        got = []
        bus.subscribe("hexbot/disc/ping", lambda k, p: got.append(p))
        print("ready", flush=True)
        clock.run(until=lambda: bool(got), timeout_s=20)
        print("got", got[0].decode() if got else None, flush=True)
        bus.close()
    """)
    p1 = subprocess.Popen([sys.executable, "-c", listener], stdout=subprocess.PIPE, text=True)
    try:
        assert p1.stdout.readline().strip() == "ready"
        talker = textwrap.dedent("""
            from bus.clock import WallClock
            from bus.transport import Bus
            clock = WallClock(); bus = Bus(clock, "disc")
            n = [0]
            def ping():
                n[0] += 1
                bus.put("hexbot/disc/ping", b"hello")
                if n[0] < 200: clock.call_later(50_000_000, ping)
            clock.call_later(0, ping)
            clock.run(timeout_s=10)
            bus.close()
        """)
        p2 = subprocess.Popen([sys.executable, "-c", talker])
        out, _ = p1.communicate(timeout=30)
        p2.kill()
        p2.wait(timeout=10)
        assert "got hello" in out
    finally:
        p1.kill()

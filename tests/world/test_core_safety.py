"""The fleet core (module_sim.core) takes light from outside it safely and exactly (issue 51,
item 6): a malformed ``ir/tx`` sample is a ``bad-sample`` event, checked in Python and again
in C; a burst longer than a board's is carried whole."""

from __future__ import annotations

import ctypes
import json
import os
import time

import numpy as np
import pytest

from bus import SessionOptions, VirtualClock, WallClock
from bus.ir import Burst
from bus.session import open_session
from bus.timing import NS_PER_S
from bus.transport import Bus
from module_sim.fleet import Fleet
from processes import free_port
from tests.support.block_fleets import block_scenarios

NS_PER_MS = 1_000_000
BYTE_NS = 4_166_667  # a byte at 2400 baud

#: (what is wrong, the sample): each an ir/tx burst the core must not read past or take
MALFORMED = [
    ("short starts", {"data": "a1b2c3", "starts": [0]}),
    ("no starts", {"data": "a1b2c3", "starts": []}),
    ("long starts", {"data": "a1", "starts": [0, 1, 2]}),
    ("short corrupt", {"data": "a1b2c3", "corrupt": [True]}),
    ("long corrupt", {"data": "a1", "corrupt": [False, True, True]}),
    ("zero byte time", {"byte_ns": 0}),
    ("huge byte time", {"byte_ns": 2**32 + 5}),
    ("negative start", {"starts": [-1, 0]}),
    ("start past 64 bits", {"starts": [2**64, 0]}),
    ("float start", {"starts": [1.5, 0]}),
    ("starts not a list", {"starts": "0,1"}),
    ("data not hex", {"data": "zz11"}),
]


def _burst(src: str, t0: int, n: int, **change) -> dict:
    """An ir/tx burst of ``src`` on its centre transceiver, ``n`` bytes from ``t0``."""
    data = bytes((i * (31 + len(src) * ord(src[-1])) + 7) & 0xFF for i in range(n))
    d = json.loads(Burst(src, 1, 0, data, [t0 + i * BYTE_NS for i in range(n)], BYTE_NS).to_json())
    if "data" in change and "starts" not in change:
        change["starts"] = d["starts"][:len(change["data"]) // 2]
    d.update(change)
    return d


def _fleet(name: str, core: bool = True, **options):
    clock = VirtualClock()
    bus = Bus(clock, name, options=SessionOptions(**options) if options else SessionOptions(isolated=True))
    fleet = Fleet(bus, block_scenarios(2, "firmware")[0], core=core)
    assert (fleet.core is not None) == core
    fleet.power_up()
    return clock, bus, fleet


def _run_until(clock, done, timeout_s: float = 30.0) -> None:
    """Run the virtual clock until ``done()``: samples from another process arrive on wall
    time, and a virtual run with nothing left to do returns before they do."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        clock.run(until=done, timeout_s=max(0.0, deadline - time.monotonic()))


def test_a_malformed_burst_from_elsewhere_is_a_bad_sample_event_and_the_core_runs_on():
    """Samples from another process on ir/tx whose lengths disagree (the core read past
    ``starts`` before) or whose times do not fit: one bad-sample event each, nothing enters
    the core, and a good burst after them still reaches the modules."""
    port = free_port()
    name = f"coresafe{os.getpid()}"
    clock, bus, fleet = _fleet(name, listen=[f"tcp/127.0.0.1:{port}"])
    other = Bus(WallClock(), name, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        events: list[dict] = []
        bus.subscribe_json(bus.keys.event("world"),
                           lambda k, d: events.append(d) if d["kind"] == "bad-sample" else None)
        clock.run(until_ns=NS_PER_S)
        assert other.wait_remote(bus.keys.ir_tx("x1"), timeout_s=15)
        for _, change in MALFORMED:
            other.put(other.keys.ir_tx("x1"), json.dumps(_burst("x1", NS_PER_S, 4, **change)).encode())
        _run_until(clock, lambda: len(events) >= len(MALFORMED))
        assert len(events) == len(MALFORMED)
        assert all(e["key"] == "ir/tx/x1" and "ValueError" in e["reason"] for e in events), events
        assert "3 bytes has 1 start times" in events[0]["reason"]
        # the core is whole: a good burst from elsewhere is taken, and the modules run on
        other.put(other.keys.ir_tx("x1"), json.dumps(_burst("x1", clock.now_ns() + NS_PER_MS, 4)).encode())
        taken = fleet.core.light_taken
        _run_until(clock, lambda: fleet.core.light_taken > taken)
        clock.run(until_ns=clock.now_ns() + 100 * NS_PER_MS)
        assert fleet.core.light_taken == taken + 1 and len(events) == len(MALFORMED)
    finally:
        other.close()
        bus.close()


@pytest.mark.parametrize("what,change", MALFORMED, ids=[w for w, _ in MALFORMED])
def test_put_light_refuses_a_malformed_burst_before_the_core_reads_it(what, change):
    clock, bus, fleet = _fleet(f"coresafe-{what.replace(' ', '-')}")
    try:
        clock.run(until_ns=NS_PER_S)
        with pytest.raises(ValueError, match="burst"):
            fleet.world._on_ir("ir/tx/x1", json.dumps(_burst("x1", NS_PER_S, 4, **change)).encode())
    finally:
        bus.close()


def test_the_core_itself_refuses_lengths_and_indexes_that_disagree():
    """core_put_light checks what Python checked: a caller that did not cannot make it read
    past its buffers (1 lengths, 2 source, 3 receiver, 4 byte time, 5 a start too late)."""
    clock, bus, fleet = _fleet("coresafe-c")
    try:
        core = fleet.core
        lib, h = core.lib, core._h
        src = lib.core_add_external_source(h)
        rcv = (ctypes.c_int32 * 1)(lib.core_receiver(h, 0, 0))
        data = b"\x01\x02\x03"
        starts = np.array([10, 20, 30], dtype=np.uint64)

        def put(n_starts=3, flags=None, n_flags=0, s=src, r=rcv, byte_ns=BYTE_NS, st=starts):
            return lib.core_put_light(h, 0, s, 1, ctypes.addressof(r), data, 3, st.ctypes.data, n_starts,
                                      byte_ns, flags, n_flags)

        assert put(n_starts=1) == 1
        assert put(flags=b"\x01", n_flags=1) == 1
        assert put(s=src + 1) == 2 and put(s=0) == 2
        assert put(r=(ctypes.c_int32 * 1)(10**6)) == 3 and put(r=(ctypes.c_int32 * 1)(-1)) == 3
        assert put(byte_ns=0) == 4
        assert put(st=np.array([10, 2**64 - 2, 30], dtype=np.uint64)) == 5
        assert put() == 0 and put(flags=b"\x00\x01\x00", n_flags=3) == 0
    finally:
        bus.close()


def _collisions(core: bool, n: int) -> list[dict]:
    """Two outside transmitters' ``n``-byte bursts overlapping at both modules."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, f"corelong{int(core)}", session=session)
    events: list[dict] = []
    bus.subscribe_json(bus.keys.event("world"), lambda k, d: events.append(d))
    try:
        fleet = Fleet(bus, block_scenarios(2, "firmware")[0], core=core)
        assert (fleet.core is not None) == core
        t0 = NS_PER_S
        clock.run(until_ns=t0)
        for src, shift in (("x1", 0), ("x2", BYTE_NS // 2)):
            bus.put(bus.keys.ir_tx(src), json.dumps(_burst(src, t0 + shift, n)).encode())
        clock.run(until_ns=t0 + (n + 2) * BYTE_NS)
        return sorted((e for e in events if e["kind"] == "collision"), key=lambda e: json.dumps(e, sort_keys=True))
    finally:
        bus.close()
        session.close()


def test_a_burst_longer_than_a_boards_is_carried_whole_as_on_the_python_path():
    """A 300-byte burst from outside (a board's is at most 255) met another: the core cut it
    to 256 bytes before; every byte is in the air, garbled as the Python medium garbles it."""
    n = 300
    core, python = _collisions(True, n), _collisions(False, n)
    assert len(core) == 2  # the second burst meets the first at each module
    assert all(len(bytes.fromhex(e["received"])) == n for e in core)
    assert core == python




def _long_window_after(t0: int) -> int:
    """When the core's first window after ``t0`` that runs 50 ms or more starts (during the
    boot of the two-module fleet): a window that would carry a burst of its instant late."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, "corewindows", session=session)
    try:
        fleet = Fleet(bus, block_scenarios(2, "firmware")[0])
        core = fleet.core
        windows: list[tuple[int, int]] = []
        run_window = core._window

        def window() -> None:
            start = clock.now_ns()
            run_window()
            windows.append((start, clock.now_ns()))

        core._window = window  # what _kick books from now on
        fleet.power_up()
        clock.run(until=lambda: bool(windows) and windows[-1][0] > t0 and windows[-1][1] - windows[-1][0] >= 50 * NS_PER_MS,
                  timeout_s=60)
        return windows[-1][0]
    finally:
        bus.close()
        session.close()


def _light_at(t: int, core: bool, forced: bool):
    """Two outside transmitters' bursts, put by one timer at ``t`` while the fleet boots,
    where the core's window is booked. Natural order: the window's timer (booked first)
    fires first and runs only instant ``t``, the next timer being due then. ``forced``: the
    window's timer fires after the bursts' timer, so the window runs while the clock's inbox
    still holds the bursts of its instant."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, f"coreorder{int(core)}{int(forced)}", session=session)
    frames: list[tuple] = []
    events: list[bytes] = []
    try:
        fleet = Fleet(bus, block_scenarios(2, "firmware")[0], core=core)
        fleet.power_up()
        clock.run(until_ns=t - 1)
        assert not core or fleet.core._timer_at == t

        def light() -> None:
            for src, shift in (("x1", 0), ("x2", BYTE_NS // 3)):
                bus.put(bus.keys.ir_tx(src), json.dumps(_burst(src, t + shift, 4)).encode())

        clock.call_at(t, light)
        if forced:
            fleet.core._timer.cancel()
            fleet.core._timer = clock.call_at(t, fleet.core._window)
        bus.subscribe_frames(lambda e: frames.append((e.sim_time_ns, e.src, e.link, e.first_byte_ns, e.raw)))
        bus.subscribe(bus.keys.event("world"), lambda k, p: events.append(p))
        clock.run(until_ns=t + NS_PER_S)
        return sorted(frames), sorted(events)
    finally:
        bus.close()
        session.close()


def test_a_burst_waiting_in_the_inbox_enters_the_core_at_its_own_instant():
    """The core's window used to run up to 100 ms ahead while bursts of its instant still
    waited in the clock's inbox: they entered late (the collision they make was stamped
    ~100 ms after it, and the modules heard them late). Forced or not, the frames and the
    world's events are the Python path's."""
    t = _long_window_after(3 * NS_PER_S)
    python, python_events = _light_at(t, False, False)
    collisions = [json.loads(e) for e in python_events if b'"collision"' in e]
    assert len(collisions) == 2 and all(c["sim_time_ns"] == t for c in collisions)
    natural, natural_events = _light_at(t, True, False)
    assert natural_events == python_events and natural == python
    forced, forced_events = _light_at(t, True, True)
    assert forced_events == python_events
    assert forced == python


def _boot(name: str, n: int, until_ns: int, frames: list[tuple]) -> None:
    """A fleet of ``n`` firmware modules on its own clock and core, booted to ``until_ns``."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, name, session=session)
    try:
        bus.subscribe_frames(lambda e: frames.append((e.sim_time_ns, e.src, e.link, e.first_byte_ns, e.raw)))
        fleet = Fleet(bus, block_scenarios(n, "firmware")[0])
        assert fleet.core is not None
        fleet.power_up()
        clock.run(until_ns=until_ns)
    finally:
        bus.close()
        session.close()


def test_two_cores_in_one_process_run_at_once_as_each_alone():
    """Each clock has its own core; the firmware's host libraries (their io block, flush hook
    and state area) were one copy per process, shared by every core: two cores stepping on
    two threads at once (ctypes lets go of the GIL) garbled each other's steps."""
    import threading

    alone: list[tuple] = []
    _boot("corealone", 12, 4 * NS_PER_S, alone)
    assert len(alone) > 100
    got: list[list[tuple]] = [[], []]
    threads = [threading.Thread(target=_boot, args=(f"coretwo{k}", 12, 4 * NS_PER_S, got[k])) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert sorted(got[0]) == sorted(alone) and sorted(got[1]) == sorted(alone)


def test_a_fleet_leaves_the_core_and_the_others_run_on():
    """Fleets A and B on one core; B is removed at 3 s and C added at 4 s: A's frames are
    those of A alone, B makes nothing after it left, C boots as it would alone (shifted by
    its power-up)."""
    until = 8 * NS_PER_S
    alone: list[tuple] = []
    _boot("corealoneA", 6, until, alone)
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    buses = {k: Bus(clock, f"corealone{k}", session=session) for k in "ABC"}
    frames: dict[str, list[tuple]] = {k: [] for k in buses}
    try:
        for k, bus in buses.items():
            bus.subscribe_frames(lambda e, k=k: frames[k].append((e.sim_time_ns, e.src, e.link, e.first_byte_ns,
                                                                  e.raw)))
        a = Fleet(buses["A"], block_scenarios(6, "firmware")[0])
        b = Fleet(buses["B"], block_scenarios(5, "firmware")[0])
        assert a.core is b.core is not None
        core = a.core
        a.power_up()
        b.power_up()
        clock.run(until_ns=3 * NS_PER_S)
        assert frames["B"]
        core.remove_fleet(b.world)
        left_at = clock.now_ns()
        made = len(frames["B"])
        clock.run(until_ns=4 * NS_PER_S)
        c = Fleet(buses["C"], block_scenarios(4, "firmware")[0])
        assert c.core is core
        c.power_up()
        clock.run(until_ns=until)
        assert sorted(frames["A"]) == sorted(alone)
        assert len(frames["B"]) == made and all(f[0] <= left_at for f in frames["B"])
        c_alone: list[tuple] = []
        _boot("corealoneC", 4, until - 4 * NS_PER_S, c_alone)
        shifted = sorted((t + 4 * NS_PER_S, src, link, first + 4 * NS_PER_S, raw)
                         for t, src, link, first, raw in c_alone)
        assert len(shifted) > 20 and sorted(frames["C"]) == shifted
        assert all(m is None for m in core.modules[6:11]) and core.lib.core_error(core._h) == b""
        with pytest.raises(ValueError):
            core.remove_fleet(b.world)
    finally:
        for bus in buses.values():
            bus.close()
        session.close()

"""One virtual clock across processes (bus.lockstep): participants in processes of their own,
peer to peer or through a zenoh router, give the one-process run's events at the same sim
times; a participant killed mid-run ends the others at that window's barrier, named."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from tests.support.lockstep_toy import UNTIL_NS, WINDOW_NS, one_process
from tests.support.processes import free_port


def _toy(name: str, fleet: str, out, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tests.support.lockstep_toy", name, "--fleet", fleet,
                             "--out", str(out), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _finish(procs: list[subprocess.Popen]) -> list[tuple[int, str]]:
    out = []
    for p in procs:
        try:
            _, err = p.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            p.kill()
            _, err = p.communicate()
        out.append((p.returncode, err))
    return out


def _check_against_one_process(tmp_path, fleet: str) -> None:
    reference = one_process(fleet + "ref")
    for name in "ab":
        got = json.loads((tmp_path / f"{name}.json").read_text())
        assert got["windows"] == UNTIL_NS // WINDOW_NS
        assert got["released"] > 50  # messages really crossed processes
        assert got["log"] == [e for e in reference if e[1] == name]


@pytest.mark.parametrize("through", ["peers", "router"])
def test_two_processes_in_lockstep_give_the_one_process_events(tmp_path, through):
    port = free_port()
    fleet = f"lock{through}{os.getpid()}"
    procs: list[subprocess.Popen] = []
    if through == "router":
        router = subprocess.Popen([sys.executable, "-m", "hexbench", "router", "--listen",
                                   f"tcp/127.0.0.1:{port}"], stdout=subprocess.PIPE, text=True)
        try:
            assert router.stdout.readline().startswith("router ")
            procs = [_toy(n, fleet, tmp_path / f"{n}.json", "--mode", "client", "--connect",
                          f"tcp/127.0.0.1:{port}") for n in "ab"]
            results = _finish(procs)
        finally:
            router.terminate()
            router.wait(timeout=30)
    else:
        procs = [_toy("a", fleet, tmp_path / "a.json", "--listen", f"tcp/127.0.0.1:{port}"),
                 _toy("b", fleet, tmp_path / "b.json", "--connect", f"tcp/127.0.0.1:{port}")]
        results = _finish(procs)
    assert [rc for rc, _ in results] == [0, 0], results
    _check_against_one_process(tmp_path, fleet)


def test_a_participant_killed_mid_run_ends_the_other_at_that_window(tmp_path):
    port = free_port()
    fleet = f"lockkill{os.getpid()}"
    a = _toy("a", fleet, tmp_path / "a.json", "--listen", f"tcp/127.0.0.1:{port}")
    b = _toy("b", fleet, tmp_path / "b.json", "--connect", f"tcp/127.0.0.1:{port}", "--die-in-window", "10")
    (rc_a, err_a), (rc_b, _) = _finish([a, b])
    assert rc_b == -9
    assert rc_a == 3, err_a
    # b died in window 10; its word on window 9 may have died with it, still queued
    m = re.search(r"b left the run in window (9|10) \(sim ([\d.]+)-([\d.]+) s\)", err_a)
    assert m, err_a
    k = int(m.group(1))
    assert (float(m.group(2)), float(m.group(3))) == (k * 0.02, (k + 1) * 0.02)
    got = json.loads((tmp_path / "a.json").read_text())
    assert got["windows"] == k  # it finished windows 0..k-1 and stopped at k's barrier
    assert got["log"] == [e for e in one_process(fleet + "ref") if e[1] == "a" and e[0] < (k + 1) * WINDOW_NS]


def test_a_peers_samples_of_its_next_window_wait_for_their_own_boundary():
    """A peer that crossed a boundary first sends its next window's samples behind its word:
    the boundary hands over only what came before that word (handled there, the rest would
    come a window before its time, or not, as the threads went)."""
    from bus.lockstep import LockstepClock

    clock = LockstepClock()
    handled: list[tuple[int, str]] = []

    def take(what: str) -> None:
        handled.append((clock.now_ns(), what))

    clock.post_foreign("s1", take, "s1 in window 0")
    clock.post_foreign("s0", take, "s0 in window 0")
    clock.mark_window("s0", 0)
    clock.post_foreign("s0", take, "s0 in window 1")  # s0 is ahead: s1 has not said 0 yet
    clock.mark_window("s1", 0)
    assert clock.release(30, 0) == 2
    assert handled == [(30, "s0 in window 0"), (30, "s1 in window 0")]
    assert clock.release(60, 1) == 0  # no word on window 1 from s0 yet: nothing of it is due
    clock.mark_window("s0", 1)
    clock.mark_window("s1", 1)
    assert clock.release(90, 2) == 1
    assert handled[2:] == [(90, "s0 in window 1")]


def test_a_participant_that_runs_behind_takes_its_peers_next_window_at_its_start():
    """A participant one window behind (the planner's process of a sharded run) ends window k
    with its peers' samples of window k + 1: handled at the boundary, before their time, so
    light from every shard is there before the window in which it is decoded."""
    from bus.lockstep import LockstepClock

    clock = LockstepClock()
    handled: list[tuple[int, str]] = []
    clock.post_foreign("s0", lambda: handled.append((clock.now_ns(), "s0 in window 0")))
    clock.mark_window("s0", 0)
    clock.post_foreign("s0", lambda: handled.append((clock.now_ns(), "s0 in window 1")))
    clock.mark_window("s0", 1)
    clock.post_foreign("s0", lambda: handled.append((clock.now_ns(), "s0 in window 2")))
    assert clock.release(30, 0, {"s0": 1}) == 2
    assert handled == [(30, "s0 in window 0"), (30, "s0 in window 1")]

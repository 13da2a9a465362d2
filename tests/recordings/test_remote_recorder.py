"""A virtual run's samples reach other processes too (ARCHITECTURE principle 1): the bus hands
them to this process's subscribers itself, and to zenoh for everyone else, with blocking
congestion control, so a recorder in another process gets every one of them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections import Counter

import pytest

from hexbench.cli import main
from processes import free_port
from recordings.reader import iter_samples, read_frames


def _frames(path) -> list[tuple]:
    return [(e.link, e.src, e.seq, e.sim_time_ns, e.raw) for e in read_frames(path)]


def _remote_recorder(port: int, fleet: str, out) -> subprocess.Popen:
    """``hexbench record`` in its own process, listening on loopback for the fleet."""
    return subprocess.Popen([sys.executable, "-m", "hexbench", "record", "--listen",
                             f"tcp/127.0.0.1:{port}", "--fleet", fleet, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


@pytest.mark.parametrize("program", ["model", "firmware"])  # firmware: the fleet core's batches
def test_a_recorder_in_another_process_gets_every_sample(tmp_path, capsys, program):
    port = free_port()
    fleet = f"remote{program[0]}{os.getpid()}"
    remote = tmp_path / "remote.mcap"
    rec = _remote_recorder(port, fleet, remote)
    try:
        assert rec.stdout.readline().startswith("recording "), rec.stderr.read()
        local = tmp_path / "local.mcap"
        assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual",
                     "--program", program, "--connect", f"tcp/127.0.0.1:{port}", "--fleet", fleet,
                     "--record", str(local)]) == 0
        capsys.readouterr()
    finally:
        rec.send_signal(signal.SIGTERM)
        _, err = rec.communicate(timeout=60)
    assert rec.returncode == 0, err
    here = Counter(s.topic for s in iter_samples(local))
    there = Counter(s.topic for s in iter_samples(remote))
    assert sum(here.values()) > 300
    assert there == here
    assert sorted(_frames(remote)) == sorted(_frames(local))


def test_a_burst_of_50_000_frames_reaches_a_remote_recorder_whole(tmp_path):
    """Blocking congestion control: a publisher faster than the recorder is slowed down, it
    loses nothing (zenoh's default drops: issue 31 saw 2.3 % vanish at 9 700 samples/s)."""
    import time

    from bus import Frame, Kind, Link, SessionOptions, WallClock
    from bus.transport import Bus

    port = free_port()
    fleet = f"burst{os.getpid()}"
    remote = tmp_path / "burst.mcap"
    rec = _remote_recorder(port, fleet, remote)
    n = 50_000
    bus = Bus(WallClock(), fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    try:
        assert rec.stdout.readline().startswith("recording "), rec.stderr.read()
        probe = Frame(Link.DEBUG, Kind.NOISE, b"\x00", {"reason": "burst test"})
        # a route exists only once the recorder's subscription is known here
        assert bus.wait_remote(bus.keys.frame("debug", "burst"), timeout_s=30)
        t0 = time.perf_counter()
        for _ in range(n):
            bus.publish_frame(probe, src="burst", dst="terminal")
        rate = n / (time.perf_counter() - t0)
    finally:
        bus.close()
        rec.send_signal(signal.SIGTERM)
        _, err = rec.communicate(timeout=120)
    assert rec.returncode == 0, err
    seqs = sorted(e.seq for e in read_frames(remote) if e.src == "burst")
    assert seqs == list(range(n)), f"{n - len(seqs)} of {n} frames lost at {rate:,.0f} frames/s; {err}"
    assert rate >= 10_000


def test_a_recorder_far_behind_still_gets_the_tail_when_the_publisher_closes(tmp_path):
    """A closing session drops what its links still queue: ``Bus.close()`` first waits for the
    flush barrier, answered by the recorder once it holds every sample put before it. The
    recorder is kept behind by stopping it most of the time: 8 000-10 000 of 20 000 frames are
    lost without the barrier. (Starved harder, to 3 %, zenoh sometimes ended the flush query
    after 2-3 s with no answer at all, and the tail was lost: a limit of that throttle, not
    of a recorder that is merely slow.)"""
    import threading

    from bus import Frame, Kind, Link, SessionOptions, WallClock
    from bus.transport import Bus

    port = free_port()
    fleet = f"behind{os.getpid()}"
    remote = tmp_path / "behind.mcap"
    rec = _remote_recorder(port, fleet, remote)
    n = 20_000
    bus = Bus(WallClock(), fleet, options=SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
    stop = threading.Event()

    def hold_back() -> None:
        while not stop.is_set():
            os.kill(rec.pid, signal.SIGSTOP)
            stop.wait(0.15)
            os.kill(rec.pid, signal.SIGCONT)
            stop.wait(0.02)

    throttle = threading.Thread(target=hold_back)
    try:
        assert rec.stdout.readline().startswith("recording "), rec.stderr.read()
        probe = Frame(Link.DEBUG, Kind.NOISE, b"\x00", {"reason": "behind test"})
        assert bus.wait_remote(bus.keys.frame("debug", "behind"), timeout_s=30)
        throttle.start()
        for _ in range(n):
            bus.publish_frame(probe, src="behind", dst="terminal")
        bus.close()
    finally:
        stop.set()
        if throttle.is_alive():
            throttle.join()
        os.kill(rec.pid, signal.SIGCONT)
        bus.close()
        rec.send_signal(signal.SIGTERM)
        _, err = rec.communicate(timeout=120)
    assert rec.returncode == 0, err
    seqs = sorted(e.seq for e in read_frames(remote) if e.src == "behind")
    assert seqs == list(range(n)), f"{n - len(seqs)} of {n} frames lost; {err}"

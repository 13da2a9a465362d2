"""A recorder killed with SIGKILL loses at most the last second (flush interval 0.5 s)."""

from __future__ import annotations

import selectors
import signal
import subprocess
import sys
import time

import pytest

from bus.codec import Link, encode_msg1, parse
from bus.envelope import Envelope
from bus.session import SessionOptions, free_port, open_session
from recordings.reader import read_frames, summary

FLEET = "killtest"


def _wait_for_line(proc: subprocess.Popen, prefix: str, timeout_s: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if sel.select(timeout=deadline - time.monotonic()):
            line = proc.stdout.readline()
            if line.startswith(prefix):
                return line
            if not line and proc.poll() is not None:
                break
    raise AssertionError(f"recorder did not say {prefix!r}: {proc.stderr.read() if proc.poll() is not None else ''}")


def _poll(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


@pytest.mark.slow
def test_sigkill_loses_at_most_the_last_second(tmp_path):
    port = free_port()
    out = tmp_path / "kill.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hexbench", "record", "--fleet", FLEET, "--listen", f"tcp/127.0.0.1:{port}",
         "--out", str(out), "--flush-s", "0.5"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    session = None
    try:
        _wait_for_line(proc, "recording", timeout_s=30)
        session = open_session(SessionOptions(connect=[f"tcp/127.0.0.1:{port}"]))
        pub = session.declare_publisher(f"hexbot/{FLEET}/frame/side/m1.comm")
        _poll(lambda: pub.matching_status.matching, 15, "the recorder's subscription")

        sent: list[float] = []  # monotonic send time, by seq
        t_start = time.monotonic()

        def publish_some(n: int = 20) -> None:
            for _ in range(n):
                seq = len(sent)
                frame = parse(Link.SIDE, encode_msg1(seq % 99, 1, seq % 6 + 1))
                env = Envelope.of(frame, src="m1.comm", dst="*", sim_time_ns=seq * 1_000_000,
                                  wall_time_ns=time.time_ns(), seq=seq, channel=seq % 6 + 1)
                sent.append(time.monotonic())
                pub.put(env.to_json())
            time.sleep(0.01)  # a steady ~2000 frames/s publisher

        # Let time pass until the recorder has provably flushed frames and >1.5 s are in flight.
        def flushed_and_old_enough() -> bool:
            publish_some()
            return (time.monotonic() - t_start > 1.5 and out.exists()
                    and next(iter(read_frames(out)), None) is not None)

        _poll(flushed_and_old_enough, 20, "frames on disk")
        for _ in range(50):  # half a second more traffic right before the kill
            publish_some()
        t_kill = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)

    seqs = [e.seq for e in read_frames(out)]
    assert seqs == list(range(len(seqs))), "recovered frames are a gap-free prefix"
    must_have = sum(1 for t in sent if t < t_kill - 1.0)
    assert must_have > 0
    assert len(seqs) >= must_have, f"lost frames older than 1 s: {len(seqs)} of {must_have}"
    s = summary(out)
    assert not s.complete and s.tally.frames == len(seqs)
    assert s.metadata["fleet"] == FLEET and s.metadata["log_time"] == "wall"

"""What one lockstep window costs (bus.lockstep): two participants in two processes on
loopback, idle (the barrier alone) and with the toy's traffic. Prints windows per wall second
and the cost per window; docs/bus.md quotes them."""

from __future__ import annotations

import os
import subprocess
import sys

from tests.support.processes import free_port


def _pair(tmp_path, *extra: str) -> float:
    port = free_port()
    fleet = f"lockbench{os.getpid()}{len(extra)}"
    cmd = [sys.executable, "-m", "tests.support.lockstep_toy"]
    a = subprocess.Popen([*cmd, "a", "--fleet", fleet, "--out", str(tmp_path / "a.json"), "--listen",
                          f"tcp/127.0.0.1:{port}", *extra], stdout=subprocess.PIPE, text=True)
    b = subprocess.Popen([*cmd, "b", "--fleet", fleet, "--out", str(tmp_path / "b.json"), "--connect",
                          f"tcp/127.0.0.1:{port}", *extra], stdout=subprocess.PIPE, text=True)
    outs = [p.communicate(timeout=300)[0] for p in (a, b)]
    assert a.returncode == b.returncode == 0, outs
    line = [ln for ln in outs[0].splitlines() if ln.startswith("windows ")][0]
    windows, seconds = int(line.split()[1]), float(line.split()[3])
    return windows / seconds


def test_lockstep_window_cost(tmp_path):
    idle = _pair(tmp_path, "--idle", "--window-ns", "1000000")  # 2000 windows
    busy = _pair(tmp_path, "--window-ns", "1000000")
    print(f"\nlockstep, 2 processes on loopback: idle {idle:,.0f} windows/s "
          f"({1e6 / idle:.0f} us a window); with the toy's traffic {busy:,.0f} windows/s")
    assert idle > 200  # a barrier costs well under 5 ms

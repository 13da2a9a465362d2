"""``hexbench monitor --table`` under a pseudo-terminal, as a person would run it: a row per
link and sender of a fleet that boots in another process."""

from __future__ import annotations

import os
import re

from processes import free_port, run_in_pty, wall_fleet


def test_monitor_table_draws_a_row_per_module():
    port = free_port()
    fleet = f"table{os.getpid()}"
    proc = wall_fleet("pair", port, fleet, seconds=30)
    try:
        code, screen = run_in_pty(["monitor", "--table", "--seconds", "6", "--connect", f"tcp/127.0.0.1:{port}",
                                   "--fleet", fleet], timeout_s=30, columns=160)
        assert code == 0
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    text = re.sub(rb"\x1b\[[0-9;?]*[A-Za-z]", b"", screen).decode(errors="replace")
    assert f"hexbench monitor: hexbot/{fleet}" in text
    # every module's row (their comm boards print banners until about 9 s after power-up;
    # the control boards' early UART lines may be over before the monitor has joined)
    rows = {line.split("│")[2].strip() for line in text.splitlines() if line.count("│") > 5}
    assert {"m1.comm", "m2.comm"} <= rows, text[-3000:]
    assert "banner" in text  # the last frames decoded: the boot banners


def test_plain_monitor_shows_seconds_since_it_joined_not_unix_time():
    """A wall-clock fleet's samples carry Unix times: the monitor shows seconds from the first
    sample it saw, for frames and events alike."""
    from processes import hexbench
    port = free_port()
    fleet = f"plain{os.getpid()}"
    proc = wall_fleet("pair", port, fleet, seconds=30)
    try:
        mon = hexbench("monitor", "--seconds", "5", "--connect", f"tcp/127.0.0.1:{port}", "--fleet", fleet)
        out = mon.communicate(timeout=60)[0]
        assert mon.returncode == 0, out
    finally:
        proc.terminate()
        proc.communicate(timeout=30)
    lines = [line for line in out.splitlines() if re.match(r"\s*\d+\.\d{3} ", line)]
    assert lines, out
    times = [float(line.split()[0]) for line in lines]
    assert times[0] == 0.0 and max(times) < 30  # not 1.7e9
    assert all(re.match(r"\s*\d+\.\d{3} (event|\w)", line) for line in lines)

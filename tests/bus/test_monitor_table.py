"""``hexbench monitor --table`` under a pseudo-terminal, as a person would run it: a row per
link and sender of a fleet that boots in another process."""

from __future__ import annotations

import os
import pty
import re
import subprocess
import sys
import time

from processes import free_port, wall_fleet


def test_monitor_table_draws_a_row_per_module():
    port = free_port()
    fleet = f"table{os.getpid()}"
    proc = wall_fleet("pair", port, fleet, seconds=30)
    master, slave = pty.openpty()
    try:
        mon = subprocess.Popen([sys.executable, "-m", "hexbench", "monitor", "--table", "--seconds", "6",
                                "--connect", f"tcp/127.0.0.1:{port}", "--fleet", fleet],
                               stdin=slave, stdout=slave, stderr=slave,
                               env={**os.environ, "COLUMNS": "160", "LINES": "40", "TERM": "xterm"})
        os.close(slave)
        screen = b""
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the monitor exited and closed the pty
                break
            if not chunk:
                break
            screen += chunk
        assert mon.wait(timeout=30) == 0
    finally:
        os.close(master)
        proc.terminate()
        proc.communicate(timeout=30)
    text = re.sub(rb"\x1b\[[0-9;?]*[A-Za-z]", b"", screen).decode(errors="replace")
    assert f"hexbench monitor: hexbot/{fleet}" in text
    # every module's row (their comm boards print banners until about 9 s after power-up;
    # the control boards' early UART lines may be over before the monitor has joined)
    rows = {line.split("│")[2].strip() for line in text.splitlines() if line.count("│") > 5}
    assert {"m1.comm", "m2.comm"} <= rows, text[-3000:]
    assert "banner" in text  # the last frames decoded: the boot banners

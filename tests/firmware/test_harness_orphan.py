"""A simavr module outlives nobody: its harness runs in a session of its own (so a terminal's
Ctrl-C does not reach it twice), and stops by itself when the process that started it dies
without a word (SIGKILL), instead of running forever behind its ptys."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from toolchain import needs_avr

pytestmark = needs_avr

STARTER = """
import sys, time
from hil.firmware import FirmwareModule
m = FirmwareModule(5).start()
print(m.proc.pid, flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:  # a zombie has exited
        return f.read().split(") ")[1][0] != "Z"


def test_the_harness_stops_when_its_starter_is_killed():
    starter = subprocess.Popen([sys.executable, "-c", STARTER], stdout=subprocess.PIPE, text=True)
    try:
        harness = int(starter.stdout.readline())
        assert _alive(harness)
        starter.send_signal(signal.SIGKILL)
        starter.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _alive(harness) and time.monotonic() < deadline:
            time.sleep(0.05)  # polling a process we cannot wait for (not our child)
        assert not _alive(harness), "the harness outlived the process that started it"
    finally:
        starter.kill()
        starter.wait()

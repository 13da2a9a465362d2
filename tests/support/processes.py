"""hexbench commands in processes of their own, for tests of what crosses process borders."""

from __future__ import annotations

import os
import subprocess
import sys


def hexbench(*args: str) -> subprocess.Popen:
    """``python -m hexbench ARGS`` with its output in a pipe (unbuffered: lines as they come)."""
    return subprocess.Popen([sys.executable, "-m", "hexbench", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})


def wall_fleet(scenario: str, port: int, fleet: str, seconds: float = 60) -> subprocess.Popen:
    """``hexbench fleet SCENARIO --clock wall`` listening on loopback ``port``; returns once it
    printed its first line (the fleet is on the bus; its modules are still booting)."""
    proc = hexbench("fleet", scenario, "--clock", "wall", "--listen", f"tcp/127.0.0.1:{port}",
                    "--fleet", fleet, "--seconds", f"{seconds:g}")
    line = proc.stdout.readline()
    if not line.startswith(f"fleet {scenario}:"):
        proc.kill()
        raise AssertionError(f"the fleet did not start: {line}{proc.communicate()[0]}")
    return proc


def free_port() -> int:
    """A TCP port nobody listens on now (the kernel's choice), for a zenoh listener."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

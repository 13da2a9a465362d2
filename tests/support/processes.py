"""hexbench commands in processes of their own, for tests of what crosses process borders."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

from bus.session import free_port  # noqa: F401  (the tests' ports: one function with the application's)


def _ctrl_c_as_on_a_terminal() -> None:
    # A shell starts a background job with SIGINT ignored, and Python then installs no
    # KeyboardInterrupt: tests that press Ctrl-C (SIGINT) must reach the command's own handler
    # wherever the suite was started from.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def hexbench(*args: str) -> subprocess.Popen:
    """``python -m hexbench ARGS`` with its output in a pipe (unbuffered: lines as they come)."""
    return subprocess.Popen([sys.executable, "-m", "hexbench", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, preexec_fn=_ctrl_c_as_on_a_terminal,
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


def run_in_pty(args: list[str], *, timeout_s: float = 120, columns: int = 120, lines: int = 40) -> tuple[int, bytes]:
    """``python -m hexbench ARGS`` on a real pseudo-terminal (as a person runs it): its exit
    status and everything it drew, once it has ended (killed after ``timeout_s``)."""
    import pty
    import time

    leader, follower = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "hexbench", *args], stdin=follower, stdout=follower,
                            stderr=follower, close_fds=True,
                            env={**os.environ, "COLUMNS": str(columns), "LINES": str(lines), "TERM": "xterm"})
    os.close(follower)
    screen = b""
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            try:
                chunk = os.read(leader, 65536)
            except OSError:  # the child ended and closed the terminal
                break
            if not chunk:
                break
            screen += chunk
    finally:
        os.close(leader)
        if proc.poll() is None and time.monotonic() >= deadline:
            proc.kill()
    return proc.wait(timeout=30), screen

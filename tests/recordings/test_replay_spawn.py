"""``hexbench replay FILE --spawn``, the command itself, headless: it spawns a rerun viewer
and streams the replay to it. The viewer here is rerun's own gRPC server saving to a file (a
``rerun`` found first on PATH), since no window can open; what it saved is the replay."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from recordings.replay import rerun_binary

VIEWER_PORT = 9876  # rerun.spawn's: replay --spawn gives no other


def _server() -> str:
    """rerun's binary itself (the ``rerun`` script runs it as a child): its pid is the
    wrapper's, to end it by."""
    try:
        import rerun_cli
    except ImportError:
        return rerun_binary()
    exe = Path(rerun_cli.__file__).with_name("rerun")
    return str(exe) if exe.exists() else rerun_binary()


def _viewer(d: Path) -> Path:
    """A ``rerun`` for PATH that records how it was started and runs a saving server instead
    of a window, on the port it was given (its output in a file: the replay, which spawned it
    detached, must not wait for it)."""
    exe = d / "rerun"
    exe.write_text(f"""#!/bin/sh
echo "$@" >> {d / 'args'}
case "$1" in --version) exec {_server()} "$@";; esac  # spawn asks it first
echo $$ > {d / 'pid'}
port={VIEWER_PORT}
for a in "$@"; do case "$a" in --port=*) port=${{a#--port=}};; esac; done
exec {_server()} --save {d / 'viewer.rrd'} --bind 127.0.0.1 --port "$port" \
     < /dev/null > {d / 'viewer.log'} 2>&1
""")
    exe.chmod(0o755)
    return exe


def _entities(rrd: Path) -> set[str]:
    with warnings.catch_warnings():  # the server's file has no footer while it runs: read it whole
        warnings.simplefilter("ignore")
        return {c.entity_path for c in RrdReader(rrd).stream()}


def test_replay_spawn_opens_a_viewer_and_streams_the_replay_to_it(recorded, rerun_bin, tmp_path):
    with socket.socket() as s:
        if s.connect_ex(("127.0.0.1", VIEWER_PORT)) == 0:
            pytest.skip(f"a rerun viewer already listens on {VIEWER_PORT}: --spawn would use it")
    _viewer(tmp_path)
    env = {**os.environ, "PATH": f"{tmp_path}{os.pathsep}{os.environ['PATH']}"}
    try:
        r = subprocess.run([sys.executable, "-m", "hexbench", "replay", str(recorded.path), "--spawn"],
                           env=env, capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert re.match(r"[1-9]\d* samples, [1-9]\d* frames", r.stderr.splitlines()[-1]), r.stderr
        assert f"--port={VIEWER_PORT}" in (tmp_path / "args").read_text()  # a viewer was spawned
        want = {"/world/lattice", "/frames/pc"}
        deadline, seen = time.monotonic() + 30, set()
        while time.monotonic() < deadline and not want <= seen:
            time.sleep(0.2)
            try:
                seen = _entities(tmp_path / "viewer.rrd")
            except Exception:  # not written yet, or a message half written: read again
                pass
        assert want <= seen, sorted(seen)
    finally:
        pid = tmp_path / "pid"
        if pid.exists():
            try:
                os.kill(int(pid.read_text()), signal.SIGKILL)
            except ProcessLookupError:
                pass

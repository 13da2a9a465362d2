"""A checkout whose firmware sources changed after its last build (a pull, an edit) rebuilds
the host libraries before a module runs them: a stale library beside a changed Python model
made the two programs part silently (a Walter run failed its first round)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from bus.cheader import FIRMWARE_DIR, build_path


def test_a_changed_source_rebuilds_the_host_library_before_it_runs(tmp_path):
    lib = build_path("lib", "comm", "v2")
    assert lib.exists() and lib.parent == FIRMWARE_DIR / "build", "make firmware first"
    copy = tmp_path / "firmware"
    shutil.copytree(FIRMWARE_DIR, copy, symlinks=True)
    built = copy / "build" / lib.name
    before = built.stat().st_mtime_ns
    source = copy / "src" / "comm.c"
    os.utime(source, ns=(before + 10**9, before + 10**9))  # edited after the build
    env = dict(os.environ, HEXBENCH_FIRMWARE=str(copy))
    load = [sys.executable, "-c", "from module_sim.firmware import Program; from bus.cheader import build_path; Program.get('comm', 'v2'); print(build_path('lib', 'comm', 'v2'))"]
    r = subprocess.run(load, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert Path(r.stdout.strip()) == built
    assert built.stat().st_mtime_ns > before + 10**9  # remade from the newer source
    # up to date now: the next process loads it as it is
    again = built.stat().st_mtime_ns
    assert subprocess.run(load, env=env, capture_output=True, timeout=300).returncode == 0
    assert built.stat().st_mtime_ns == again

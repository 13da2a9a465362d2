"""The fleet core built with AddressSanitizer takes fuzzed ``ir/tx`` samples clean (issue 51,
item 6). The core is loaded by an uninstrumented Python, so the run is a subprocess with
libasan preloaded (tests/support/core_fuzz.py)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from toolchain import missing

ROOT = Path(__file__).resolve().parents[2]
CORE = ROOT / "module_sim" / "core"
FUZZ = ROOT / "tests" / "support" / "core_fuzz.py"


@pytest.fixture(scope="module")
def asan_core() -> tuple[Path, dict[str, str]]:
    """The ASan build of libhexcore, and the environment that loads libasan first."""
    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        missing(f"a C compiler ({cc})")
    libasan = subprocess.run([cc, "-print-file-name=libasan.so"], capture_output=True, text=True).stdout.strip()
    if not os.path.isabs(libasan) or not Path(libasan).exists():
        missing(f"libasan for {cc}", "apt-get install libasan8")
    subprocess.run(["make", "-s", "-C", str(CORE), "build/libhexcore-asan.so"], check=True)
    env = dict(os.environ, LD_PRELOAD=libasan, ASAN_OPTIONS="detect_leaks=0:abort_on_error=0")
    return CORE / "build" / "libhexcore-asan.so", env


def _fuzz(lib: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(FUZZ), str(lib), *args], env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def test_the_asan_target_sees_a_read_past_starts(asan_core):
    """The target is live: C told more start times than it is given (what a short ``starts``
    did through put_light before) is a heap-buffer-overflow report, not silence."""
    run = _fuzz(*asan_core, "--canary")
    assert run.returncode != 0 and "heap-buffer-overflow" in run.stderr, run.stderr[-2000:]
    assert "core_put_light" in run.stderr


@pytest.mark.slow
def test_fuzzed_ir_tx_samples_run_clean_on_the_asan_core(asan_core):
    """Hypothesis-made bursts (too long, lengths and times that disagree, fields of the wrong
    type) through the world into the core, and the same lengths straight into C: no report,
    and both kinds (taken, refused) were exercised."""
    run = _fuzz(*asan_core, "--examples", "300")
    assert run.returncode == 0 and "AddressSanitizer" not in run.stderr, run.stderr[-3000:]
    counts = dict(zip(*[iter(run.stdout.split())] * 2))
    assert int(counts["taken"]) > 30 and int(counts["refused"]) > 30 and int(counts["c-refused"]) > 30, run.stdout

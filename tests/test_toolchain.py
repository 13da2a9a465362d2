"""A test that needs a missing tool is skipped on a desk, visibly, and fails in CI (issue 50,
item 15): ``make test`` and ``.ci/run`` say CI with ``HEXBENCH_REQUIRE_TOOLS=1``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PROBE = """
from toolchain import module, needs_tools


@needs_tools("hexbench-no-such-tool")
def test_runs_a_program():
    pass


def test_imports_a_module():
    module("hexbench_no_such_module")
"""


def _pytest(tmp_path: Path, **env: str) -> subprocess.CompletedProcess:
    """The probe under the project's pytest configuration, with ``env`` as the only CI hint."""
    (tmp_path / "test_probe.py").write_text(PROBE)
    (tmp_path / "conftest.py").write_text((ROOT / "tests" / "conftest.py").read_text())
    clean = {k: v for k, v in os.environ.items() if k not in ("CI", "HEXBENCH_REQUIRE_TOOLS")}
    return subprocess.run([sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"),
                           "-q", "-n", "0", str(tmp_path)], cwd=ROOT, env=clean | env,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("env", [{}, {"HEXBENCH_REQUIRE_TOOLS": "0"}], ids=["desk", "required-off"])
def test_a_missing_tool_is_a_skip_listed_with_its_reason_on_a_desk(tmp_path, env):
    r = _pytest(tmp_path, **env)
    assert r.returncode == 0, r.stdout
    assert "2 skipped" in r.stdout
    assert "SKIPPED [1] " in r.stdout and "needs hexbench-no-such-tool (make test installs it" in r.stdout
    assert "needs the Python module hexbench_no_such_module (pip install" in r.stdout


@pytest.mark.parametrize("env", [{"CI": "true"}, {"HEXBENCH_REQUIRE_TOOLS": "1"}], ids=["CI", "required"])
def test_a_missing_tool_fails_in_ci(tmp_path, env):
    r = _pytest(tmp_path, **env)
    assert r.returncode == 1, r.stdout
    assert "skipped" not in r.stdout
    assert "1 failed, 1 error" in r.stdout  # the program at setup, the module in the test
    assert r.stdout.count("missing, and CI runs every test (CI / HEXBENCH_REQUIRE_TOOLS)") >= 2


def test_make_test_and_ci_require_every_tool():
    r = subprocess.run(["make", "-n", "test"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    runs = [line for line in r.stdout.splitlines() if " -m pytest " in line]
    assert len(runs) == 3 and all(line.startswith("HEXBENCH_REQUIRE_TOOLS=1 ") for line in runs), r.stdout
    assert "export HEXBENCH_REQUIRE_TOOLS=1" in (ROOT / ".ci" / "run").read_text()

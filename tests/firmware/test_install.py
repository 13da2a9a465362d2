"""hexbench installs like a Python package: ``pip install <checkout>`` (not editable, as pipx or
a CI image installs it) builds the firmware's host libraries into the wheel, so an installed
hexbench with no checkout beside it runs the firmware on the fleet core by default and gives the
golden frames; one installed without them says what is missing in one line (and by default runs
the Python programs, saying why)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from golden import GOLDEN_THESIS_12_FRAMES, frames_digest
from toolchain import needs_tools

ROOT = Path(__file__).resolve().parents[2]

pytestmark = needs_tools("cc")


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict[str, str]]:
    """hexbench installed from the checkout into a directory of its own, and the environment of
    a bare venv that sees it and the dependencies, but not the editable checkout (the .pth of
    the editable install is not read from a PYTHONPATH entry)."""
    tmp = tmp_path_factory.mktemp("install")
    site = tmp / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(site),
                        str(ROOT)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(tmp / "v")], check=True, timeout=120)
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp),
           "PYTHONPATH": f"{site}:{sysconfig.get_paths()['purelib']}"}
    return tmp, env


def _run(tmp: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(tmp / "v" / "bin" / "python"), *args], cwd=tmp, env=env,
                          capture_output=True, text=True, timeout=600)


def test_an_installed_hexbench_runs_the_firmware_and_gives_the_golden_frames(installed):
    tmp, env = installed
    where = _run(tmp, env, "-c", "import hexbench, bus.cheader as c; "
                                 "print(hexbench.__file__); print(c.build_path('lib', 'comm', 'v2'))")
    assert where.returncode == 0, where.stderr
    module, lib = where.stdout.split()
    assert module.startswith(str(tmp / "site")) and lib.startswith(str(tmp / "site" / "bus" / "_firmware"))
    r = _run(tmp, env, "-m", "hexbench", "run", "thesis-12", "--planner", "complete", "--clock", "virtual",
             "--record", "x.mcap")  # no --program: the default, the firmware on the fleet core
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "program: the Python programs" not in r.stdout, r.stdout[-2000:]
    assert frames_digest(tmp / "x.mcap") == GOLDEN_THESIS_12_FRAMES


def test_an_install_without_the_libraries_says_what_is_missing(installed):
    tmp, env = installed
    bare = tmp / "bare"
    if not bare.exists():
        shutil.copytree(tmp / "site", bare)
        shutil.rmtree(bare / "bus" / "_firmware")
    env = dict(env, PYTHONPATH=env["PYTHONPATH"].replace(str(tmp / "site"), str(bare)))
    r = _run(tmp, env, "-m", "hexbench", "run", "pair", "--planner", "complete", "--clock", "virtual",
             "--program", "firmware")
    assert r.returncode != 0
    assert "installed without its firmware's host libraries" in r.stdout + r.stderr, r.stdout + r.stderr
    assert "Traceback" not in r.stderr
    # the default program takes the Python path there, saying why
    r = _run(tmp, env, "-m", "hexbench", "run", "pair", "--planner", "complete", "--clock", "virtual")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "program: the Python programs, not the C firmware on the fleet core: " in r.stdout
    assert "installed without its firmware's host libraries" in r.stdout

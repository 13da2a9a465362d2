"""``hexbench firmware build|run|diff``, the commands themselves, as a person types them (the
functions behind them have tests of their own: test_simavr_harness, test_differential)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest

from toolchain import module, needs_avr

pytestmark = needs_avr

IMAGES = ("comm-v2.elf", "control-v2.elf", "comm-thesis.elf", "control-thesis.elf")


def _hexbench(*args: str, timeout: float) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hexbench", *args], capture_output=True, text=True,
                          timeout=timeout)


def test_firmware_build_exits_0_and_prints_the_sizes():
    r = _hexbench("firmware", "build", timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    sizes = {m[1]: (int(m[2]), int(m[3])) for m in re.finditer(
        r"^(\S+\.elf)\s+flash\s+(\d+) / 16384 B\s+RAM\s+(\d+) / 768 B", r.stdout, re.M)}
    assert set(sizes) == set(IMAGES), r.stdout
    assert all(0 < flash <= 16384 and 0 < ram <= 768 for flash, ram in sizes.values())


def test_firmware_run_answers_on_its_ptys_and_stops_after_seconds(tmp_path):
    """``--module 3 --seconds 3``: the control board's boot banner on the debug pty, then the
    command ends by itself, its pty links gone."""
    serial = module("serial")
    ir, debug = tmp_path / "m3", tmp_path / "m3d"
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "hexbench", "firmware", "run", "--module", "3",
                             "--seconds", "3", "--link", str(ir), "--debug-link", str(debug)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line == f"firmware m3 (v2) in simavr: IR on {ir}, debug UART1 on {debug}\n", \
            line + proc.stderr.read() if proc.poll() is not None else line
        heard = b""
        with serial.Serial(str(debug), 4800, timeout=0.2) as port:
            while b"COMM. BOARD READY" not in heard and time.monotonic() - start < 10:
                heard += port.read(64)
        assert b"CTR. BOARD READY" in heard and b"COMM. BOARD READY" in heard, heard
        assert os.path.islink(ir) and os.readlink(ir).startswith("/dev/pts/")
        assert proc.wait(timeout=15) == 0, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert time.monotonic() - start < 15
    assert not os.path.lexists(ir) and not os.path.lexists(debug)


@pytest.mark.parametrize("profile", [None, "thesis-2009"])
def test_firmware_diff_says_same(profile):
    """The default profile (v2) and the thesis one: the model and the firmware give the same
    streams; exit 0, "same" last."""
    r = _hexbench("firmware", "diff", *(["--profile", profile] if profile else []), timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    lines = r.stdout.splitlines()
    assert lines[0].startswith(f"firmware diff ({profile or 'v2'}, ") and lines[-1] == "same", r.stdout

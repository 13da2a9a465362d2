"""Firmware modules as fleet members: the C programs in simavr, bridged like real boards
(``hexbench run --firmware ID``), with twins in the world; and the C programs compiled for the
host as every virtual module's program, on the wall clock. The runs start together and each
test waits for its own (about 45 s of wall clock)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from mcap.reader import make_reader
from toolchain import needs_avr
from wall_clock import heard

ROOT = Path(__file__).resolve().parents[2]
pytestmark = [needs_avr, pytest.mark.wall_clock]  # wall clock: tests/support/wall_clock.py

RUNS = {
    # the reference is the firmware: its twin's side light localizes the virtual module
    "reference": ["pair", "--planner", f"script:{ROOT}/docs/scripts/pair-rotate.txt", "--firmware", "1"],
    # the mobile module is the firmware: it moves, its ACT reports drive its body
    "mobile": ["pair", "--planner", f"script:{ROOT}/docs/scripts/pair-rotate-real.txt", "--firmware", "2"],
    # every virtual module runs the C firmware compiled for the host, on the wall clock
    "host": ["pair", "--planner", f"script:{ROOT}/docs/scripts/pair-rotate.txt", "--program", "firmware"],
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from hil.firmware import ensure_built

    ensure_built()
    base = tmp_path_factory.mktemp("firmware-fleet")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = {}
    for name, args in RUNS.items():
        (base / name).mkdir()
        procs[name] = subprocess.Popen(
            [sys.executable, "-m", "hexbench", "run", *args, "--clock", "wall", "--record", "run.mcap",
             "--isolated", "--fleet", f"fw-{name}"],
            cwd=base / name, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    done = {}
    try:
        yield lambda name: done.setdefault(name, _finish(procs[name], base / name))
    finally:
        for p in procs.values():
            p.kill()


def _finish(proc, where: Path):
    out = heard(proc.communicate(timeout=300)[0])
    with open(where / "run.mcap", "rb") as f:
        recs = [(ch.topic, json.loads(m.data)) for _, ch, m in make_reader(f).iter_messages()
                if ch.message_encoding == "json"]  # not the foxglove/* channels
    return proc.returncode, out, recs


def test_firmware_reference_in_the_thesis_experiment(runs):
    code, out, recs = runs("reference")
    assert code == 0, out
    assert "the world is at the goal" in out and "script finished" in out
    serial = Counter((d["src"], d["kind"]) for t, d in recs if t.startswith("frame/") and d["origin"] == "serial")
    # the firmware's own answers, through its pty: the Ref ACK, its boot banners, its debug lines
    assert serial[("hil.m1-ir", "ack")] >= 1 and serial[("m1.ctrl", "debug-msg")] >= 1
    assert not [d for t, d in recs if t.startswith("event/") and d["kind"] == "twin-diverged"], out
    assert out.count("no divergence") == 2, out  # centre and debug, answer for answer


def test_firmware_mobile_module_moves_by_its_own_reports(runs):
    code, out, recs = runs("mobile")
    assert code == 0, out
    assert "the world is at the goal" in out
    moved = [d["module"] for t, d in recs if t == "world/event" and d["kind"] == "move-completed"]
    assert moved == ["m2"]
    # the firmware's ACT lines reached the world as the body's actuators (origin serial)
    assert Counter(d["origin"] for t, d in recs if t == "world/actuators/m2")["serial"] > 0
    acts = [d for t, d in recs if t == "frame/debug/m2.ctrl" and d["kind"] == "actuators"]
    assert Counter(d["origin"] for d in acts)["serial"] == Counter(d["origin"] for d in acts)["twin"] > 0
    assert not [d for t, d in recs if t.startswith("event/") and d["kind"] == "twin-diverged"]


def test_host_firmware_on_the_wall_clock(runs):
    code, out, recs = runs("host")
    assert code == 0, out
    assert "the world is at the goal" in out and "script finished" in out
    positions = [d for t, d in recs if t == "frame/centre/m2.comm" and d["kind"] == "position"]
    assert [(p["view"]["x"], p["view"]["y"]) for p in positions] == [(1, 0), (0, 1)]

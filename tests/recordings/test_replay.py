"""The rerun replay: a valid .rrd whose final poses are the published ones."""

from __future__ import annotations

import subprocess
from datetime import timedelta

import numpy as np
import pytest
from rerun.chunk import RrdReader

from hexbench.cli import main
from recordings.player import Player
from recordings.scene import Move, rest
from bus.lattice import Cell


@pytest.fixture(scope="module")
def rrd(recorded, tmp_path_factory):
    out = tmp_path_factory.mktemp("rrd") / "run.rrd"
    assert main(["replay", str(recorded.path), "--rrd", str(out)]) == 0
    return out


def test_rrd_verifies(rrd, rerun_bin):
    res = subprocess.run([rerun_bin, "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr


def _last_pose(rrd_path, module):
    """The last (x, y, orientation) logged on ``/world/modules/<module>`` (by sim_time)."""
    rows = []
    for chunk in RrdReader(rrd_path).stream():
        if chunk.entity_path != f"/world/modules/{module}":
            continue
        d = chunk.to_record_batch().to_pydict()
        if "x" not in d:
            continue
        for t, x, y, o in zip(d["sim_time"], d["x"], d["y"], d["orientation"]):
            rows.append((t, x[0], y[0], o[0]))
    assert rows, f"no pose of {module} in the replay"
    return max(rows, key=lambda r: r[0])


def test_final_poses_are_the_published_ones(rrd, recorded):
    for m, pose in recorded.published.final_poses.items():
        t, x, y, o = _last_pose(rrd, m)
        assert (x, y, o) == (pose.x, pose.y, pose.orientation)
        assert t == timedelta(microseconds=pose.sim_time_ns // 1000)


def test_entities_cover_the_run(rrd):
    paths = {c.entity_path for c in RrdReader(rrd).stream()}
    for want in ("/world/modules/m4/magnets", "/world/modules/m4/joints", "/world/modules/m4/leds",
                 "/world/modules/m4/ir", "/frames/side", "/frames/pc", "/planner/value",
                 "/planner/electrons", "/planner/pairs", "/plots/energy/run_j", "/plots/fps/side",
                 "/events/world", "/events/recorder", "/world/lattice"):
        assert want in paths, want


def test_moves_are_animated_about_the_pivot(recorded):
    """In-between outlines of a moving module rotate about the pivot: its distance is kept."""
    player = Player(recorded.path)
    ev = next(v for _, _, v in player.items() if getattr(v, "kind", "") == "move-started")
    move = Move.from_event(ev.sim_time_ns, ev.data, rest(Cell(*ev.data["from"]), ev.data["orientation_before"]))
    assert move is not None
    pivot = np.array(ev.data["pivot"])
    r0 = np.linalg.norm(move.at(move.t0_ns).centre() - pivot)
    mids = [move.at(t) for t in move.frame_times(20_000_000)]
    assert len(mids) >= 10
    assert all(abs(np.linalg.norm(p.centre() - pivot) - r0) < 1e-9 for p in mids)
    end = move.at(move.end_ns).centre()
    assert np.allclose(end, Cell(*ev.data["to"]).centre())


def test_replay_needs_a_destination(recorded, capsys):
    assert main(["replay", str(recorded.path)]) == 2

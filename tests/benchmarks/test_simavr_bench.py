"""thesis-12 with every module the flashed images in simavr (``--program simavr``): the
real-time factor (sim seconds per wall second) in one process and over two shards, and its
frames against the host-built firmware's. Prints the figures; docs/benchmarks.md quotes them.
Target (issue 41): at least 1.0x in one process."""

from __future__ import annotations

import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

from bus.timing import TICK_NS
from recordings.reader import read_frames

ROOT = Path(__file__).resolve().parents[2]


def _run(tmp_path, name: str, *extra: str) -> tuple[float, float, list]:
    out = tmp_path / f"{name}.mcap"
    r = subprocess.run([sys.executable, "-m", "hexbench", "run", "thesis-12", "--planner", "complete",
                        "--clock", "virtual", "--record", str(out), *extra],
                       cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "complete: goal reached" in r.stdout
    m = re.search(r"run ([\d.]+) s sim / ([\d.]+) s wall", r.stdout)
    frames = sorted((e.sim_time_ns, e.link, e.src, e.dst, e.raw) for e in read_frames(out))
    return float(m[1]), float(m[2]), frames


def test_thesis_12_simavr_real_time_factor(tmp_path):
    sim, wall, frames = _run(tmp_path, "one", "--program", "simavr")
    sim2, wall2, sharded = _run(tmp_path, "shards", "--program", "simavr", "--shards", "2",
                                "--fleet", f"simavrbench{id(tmp_path)}")
    _, host_wall, host = _run(tmp_path, "host", "--program", "firmware")

    def centre(rows):
        return [r for r in rows if r[1] in ("centre", "pc")]

    def wires(rows):
        d = defaultdict(list)
        for r in rows:
            d[r[1:4]].append(r[4])
        return d

    a, b = centre(host), centre(frames)
    same = [(r[2], r[4]) for r in a] == [(r[2], r[4]) for r in b]
    worst, last_pc = 0, None
    if same:
        for i, (x, y) in enumerate(zip(a, b)):
            if x[1] == "pc":
                last_pc = i
            elif last_pc is not None:
                worst = max(worst, abs((y[0] - b[last_pc][0]) - (x[0] - a[last_pc][0])))
    drift = max((abs(y[0] - x[0]) for x, y in zip(a, b)), default=0)
    print(f"\nthesis-12 --program simavr: {sim:.1f} s sim; one process {wall:.1f} s wall, "
          f"{sim / wall:.1f}x real time; 2 shards {wall2:.1f} s wall, {sim2 / wall2:.1f}x "
          f"(--program firmware: {host_wall:.1f} s wall, {sim / host_wall:.0f}x)")
    print(f"frames: {len(frames)} (firmware {len(host)}); centre channel {len(b)} frames, "
          f"same bytes in the same order as --program firmware: {same}; every wire the same: "
          f"{wires(frames) == wires(host)}; an answer after its PC frame at most {worst / 1e6:.2f} ms "
          f"off (a tick is {TICK_NS / 1e6} ms); absolute times at most {drift / 1e6:.1f} ms off; "
          f"2 shards the one-process frames: {sharded == frames}")
    assert sim / wall >= 1.0
    assert same and sharded == frames

"""Benchmark: bring-up of the 217-module hexagon (radius 8) in robot time (sim time), one
``hexbench run`` on the virtual clock with the C firmware, stopped once the fleet is localized
(issue: Walter, bring-up in O(n + d) frames). Target: at most a fifth of the 5 117 s that polling
every module after every ``Localize`` step took, with every module localized where it is.

Run alone: ``pytest -s tests/benchmarks/test_bringup_bench.py``.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time

from hexagons import hexagon_scenario

RADIUS = 8
BEFORE_S = 5117.0  # O(n * d) polling, the same fleet (issue 49)
TARGET_S = BEFORE_S / 5


def test_hexagon_217_is_localized_in_a_fifth_of_the_polling_time(tmp_path):
    path = tmp_path / "hexagon.toml"
    path.write_text(hexagon_scenario(RADIUS, shift=1))
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "hexbench", "run", str(path), "--planner", "complete",
                          "--clock", "virtual"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen: list[str] = []
    done = None
    try:
        assert p.stdout is not None
        for line in p.stdout:
            seen.append(line)
            done = re.search(r"localized (\d+) of (\d+) modules in (\d+) Localize step\(s\) at ([\d.]+) s", line)
            if done or "could not be localized" in line:
                break
    finally:
        p.kill()
        p.wait()
    wall = time.perf_counter() - t
    assert done, "".join(seen[-20:])
    n_done, n, steps, sim_s = int(done[1]), int(done[2]), int(done[3]), float(done[4])
    print(f"\n[bring-up] {n} modules, radius {RADIUS}: {n_done} localized in {steps} Localize steps at "
          f"{sim_s:.0f} s robot time ({BEFORE_S / sim_s:.1f}x less than {BEFORE_S:.0f} s; target <= "
          f"{TARGET_S:.0f} s: {'met' if sim_s <= TARGET_S else 'MISSED'}), {wall:.0f} s wall")
    assert n_done == n == 217

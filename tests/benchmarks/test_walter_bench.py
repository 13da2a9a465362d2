"""Benchmarks of Walter, Tsai & Amato's distributed reconfiguration (issue 49): robot time to the
goal against the central planner, and the simulation's speed on a 60-module run.

Run alone: ``pytest -s tests/benchmarks/test_walter_bench.py``. Every figure is one whole
``hexbench run`` process on the virtual clock (the C firmware on the fleet core unless said).

* **Robot time** (sim time) to the goal, ``--planner walter`` against ``--planner complete`` on
  the same scenarios: generated admissible goals of 12, 20 and 40 modules (I a straight chain,
  :func:`planner_svc.planners.walter.goals.generate`) and the paper's figure scenarios. Both
  runs share the bring-up (O(n + d) frames, the same frames until the plan starts), so each
  row shows the whole run and the run after bring-up (from "localized ... at T s" to the end).
  Target: Walter's robot time at least 5x less than ``complete``'s at 40 modules; met/MISSED
  is printed for the whole run and for the run after bring-up.
* **Simulation speed**: a 60-module Walter run (generated, path cost 0) with ``--program
  firmware``, whole process (interpreter start, bring-up, rounds, world verdict), sim time over
  wall time. Target >= 100x real time; min / median / max of 3 and the load average, since other
  work on the machine slows it.

Figures are printed with met / MISSED, not asserted (timing depends on the machine); the tests
assert that every run reaches its goal.
"""

from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from planner_svc.planners.walter.goals import generate

RATIO_TARGET = 5.0  # at 40 modules
SPEED_TARGET = 100.0
#: (n, path cost class, seed): admissible goals the world accepts (generate(world_safe=True))
GENERATED = [(12, "0", 5), (20, "1", 3), (40, ">1", 2), (40, "0", 1), (40, "1", 1)]
FIGURES = ["walter-4", "walter-fig3", "walter-fig5a", "walter-fig8", "walter-fig9"]
SPEED_RUN = (60, "0", 1)

_LOCALIZED = re.compile(r"localized (\d+) of (\d+) modules in \d+ Localize step\(s\) at ([\d.]+) s")
_DONE = re.compile(r"(\w+): goal reached.* run ([\d.]+) s sim / ([\d.]+) s wall")


def generated_scenario(n: int, cost_class: str, seed: int) -> str:
    """A scenario for :func:`generate`'s goal: I as the modules, its free end first, the anchor
    (the cell I shares with G) fixed."""
    choice = generate(n, cost_class, seed).choice
    cells = lambda cs: ", ".join(f"[{c.x}, {c.y}]" for c in cs)  # noqa: E731
    anchor = choice.chain[-1]
    name = f"walter-gen{n}-cost{cost_class.replace('>', 'over')}-{seed}"
    return (f'name = "{name}"\nprofile = "v2"\nplanner = "walter"\n'
            f"fixed = [{anchor.x}, {anchor.y}]\ninitial = [{cells(choice.chain)}]\n"
            f"goal = [{cells(sorted(choice.goal))}]\n")


@dataclass
class Run:
    sim_s: float
    bringup_s: float
    wall_s: float  # the whole process

    @property
    def after_bringup_s(self) -> float:
        return self.sim_s - self.bringup_s

    @property
    def speed(self) -> float:
        return self.sim_s / self.wall_s


def run(scenario: str, planner: str, *extra: str, timeout: float = 1800) -> Run:
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "hexbench", "run", scenario, "--planner", planner,
                        "--clock", "virtual", *extra], capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t
    out = p.stdout
    done, loc = _DONE.search(out), _LOCALIZED.search(out)
    assert p.returncode == 0 and done and loc, f"{scenario} {planner}: " + (out + p.stderr)[-1500:]
    return Run(float(done.group(2)), float(loc.group(3)), wall)


def _scenarios(tmp: Path) -> list[tuple[str, int, str]]:
    rows = []
    for n, cost, seed in GENERATED:
        path = tmp / f"gen{n}-{cost}-{seed}.toml"
        path.write_text(generated_scenario(n, cost, seed))
        rows.append((f"generated n={n} cost {cost} seed {seed}", n, str(path)))
    from bus.scenario import load
    for name in FIGURES:
        rows.append((name, len(load(name).modules), name))
    return rows


def test_walter_robot_time_against_complete(tmp_path):
    print("\nrobot time to the goal (sim s): whole run | after bring-up; complete / walter")
    print(f"{'scenario':<30} {'n':>3} {'bring-up':>9} {'walter':>16} {'complete':>16} {'ratio':>13}")
    at_40: list[tuple[float, float]] = []
    for label, n, scen in _scenarios(tmp_path):
        w, c = run(scen, "walter"), run(scen, "complete")
        whole, after = c.sim_s / w.sim_s, c.after_bringup_s / w.after_bringup_s
        print(f"{label:<30} {n:>3} {w.bringup_s:>8.1f}s {w.sim_s:>7.1f} |{w.after_bringup_s:>7.1f} "
              f"{c.sim_s:>7.1f} |{c.after_bringup_s:>7.1f} {whole:>5.2f}x|{after:>5.2f}x", flush=True)
        if n == 40:
            at_40.append((whole, after))
    for k, what in enumerate(("whole run", "after bring-up")):
        worst = min(r[k] for r in at_40)
        print(f"at 40 modules, {what}: worst {worst:.2f}x less than complete (target >= "
              f"{RATIO_TARGET:.0f}x): {'met' if worst >= RATIO_TARGET else 'MISSED'}")


@pytest.mark.parametrize("program", ["firmware"])
def test_walter_60_simulation_speed(tmp_path, program):
    n, cost, seed = SPEED_RUN
    path = tmp_path / "gen60.toml"
    path.write_text(generated_scenario(n, cost, seed))
    runs = []
    for _ in range(3):
        runs.append(run(str(path), "walter", "--program", program))
        r = runs[-1]
        print(f"\nwalter n={n} cost {cost} seed {seed} --program {program}: {r.sim_s:.1f} s sim "
              f"(bring-up {r.bringup_s:.1f} s) in {r.wall_s:.1f} s wall (whole process): "
              f"{r.speed:.0f}x; load average {os.getloadavg()[0]:.2f}", flush=True)
    speeds = sorted(r.speed for r in runs)
    print(f"speed min / median / max {speeds[0]:.0f}x / {statistics.median(speeds):.0f}x / "
          f"{speeds[-1]:.0f}x; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} "
          f"(target >= {SPEED_TARGET:.0f}x, median: "
          f"{'met' if statistics.median(speeds) >= SPEED_TARGET else 'MISSED'})")

"""What the motion judge costs per coil record (module_sim/physics.py, issue 51 item 3: target
<= 5 us a record), at rest and while moves are under way.

Run alone: ``pytest -s tests/benchmarks/test_judge_bench.py``. The judge's inputs are captured
once from a real run (a 40-module Walter run, generated goal of path cost 0, the C firmware on
the fleet core): every ``on_actuators`` (a coil change the mechanics feeds it) and every
``advance`` (a wake at a deadline). They are replayed into fresh judges, the quick way (the
default) and the long way (``quick = False``: every deadline listed, every attempt evaluated at
every change; the reference, and the cost before the quick way), and printed per record:

* **at rest**: records that arrive while no body moves and no module tries to (no magnet pair on
  anywhere), e.g. the bring-up's joint and magnet tests;
* **busy**: records that arrive while moves are in flight or attempts open (Walter's rounds:
  many modules move at once), split into those that evaluate no attempt (the judge's answer
  is "this starts nothing and changes no verdict") and those that evaluate one or more;
* **whole judge**: CPU of the whole replay (changes and wakes) over the number of records.

Per-record times come from ``perf_counter_ns`` around each call (about 0.1 us of it is the
clock); the machine is shared, so read the median of 3. The replay asserts that both ways give
the same outcomes (repr and data included); the figures are printed with met / MISSED, not
asserted.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from hexbench.cli import main
from module_sim.physics import MotionJudge, ModuleSpec

sys.path.insert(0, str(Path(__file__).parent))
from test_walter_bench import generated_scenario  # noqa: E402

TARGET_US = 5.0
CAPTURE_RUN = (40, "0", 1)  # Walter: n, path cost class, seed

Call = tuple[Any, ...]  # ("a", module, t, joints, magnets) or ("t", t)


@pytest.fixture(scope="module")
def walter_inputs(tmp_path_factory) -> tuple[list[ModuleSpec], list[Any], list[Call]]:
    """The judge's construction and every call it got in one real Walter run."""
    path = tmp_path_factory.mktemp("judge") / "walter.toml"
    path.write_text(generated_scenario(*CAPTURE_RUN))
    made: list[tuple[list[ModuleSpec], list[Any]]] = []
    calls: list[Call] = []
    inside: list[int] = []
    init, on, adv = MotionJudge.__init__, MotionJudge.on_actuators, MotionJudge.advance

    def capture_init(self, modules, obstacles=(), *args, **kw):
        modules, obstacles = list(modules), list(obstacles)
        made.append((modules, obstacles))
        init(self, modules, obstacles, *args, **kw)

    def capture_on(self, module, t, joints, magnets):
        calls.append(("a", module, t, tuple(joints), tuple(magnets)))
        inside.append(1)
        try:
            return on(self, module, t, joints, magnets)
        finally:
            inside.pop()

    def capture_advance(self, t):
        if not inside:  # a wake, not on_actuators' own step to its time
            calls.append(("t", t))
        return adv(self, t)

    mp = pytest.MonkeyPatch()
    mp.setattr(MotionJudge, "__init__", capture_init)
    mp.setattr(MotionJudge, "on_actuators", capture_on)
    mp.setattr(MotionJudge, "advance", capture_advance)
    try:
        code = main(["run", str(path), "--planner", "walter", "--clock", "virtual",
                     "--program", "firmware", "--isolated"])
    finally:
        mp.undo()
    assert code == 0 and len(made) == 1, "the capture run did not reach its goal"
    return made[0][0], made[0][1], calls


def replay(inputs, quick: bool, timed: bool) -> tuple[list[str], dict[str, list[int]], float]:
    """Feed the captured calls to a fresh judge: the outcomes (repr), ns per record at rest and
    busy (``timed``), and the whole replay's CPU seconds."""
    specs, obstacles, calls = inputs
    judge = MotionJudge(specs, obstacles)
    judge.quick = quick
    on, advance = judge.on_actuators, judge.advance
    out: list[str] = []
    ns: dict[str, list[int]] = {"at rest": [], "busy, evaluates none": [], "busy, evaluates": []}
    evaluations = [0]
    if timed:
        evaluate = judge._evaluate

        def counted(*args):
            evaluations[0] += 1
            return evaluate(*args)
        judge._evaluate = counted  # type: ignore[method-assign]
    clock = time.perf_counter_ns
    cpu = time.process_time()
    for c in calls:
        if c[0] == "t":
            out.append(repr(advance(c[1])))
        elif timed:
            rest, before = not judge._flights and not judge._trying, evaluations[0]
            t0 = clock()
            r = on(c[1], c[2], c[3], c[4])
            dt = clock() - t0
            ns["at rest" if rest else "busy, evaluates" if evaluations[0] > before
               else "busy, evaluates none"].append(dt)
            out.append(repr(r))
        else:
            out.append(repr(on(c[1], c[2], c[3], c[4])))
    return out, ns, time.process_time() - cpu


def test_judge_cost_per_coil_record(walter_inputs):
    records = sum(c[0] == "a" for c in walter_inputs[2])
    wakes = len(walter_inputs[2]) - records
    n, cost, seed = CAPTURE_RUN
    print(f"\njudge inputs of a Walter run (n={n}, cost {cost}, seed {seed}, firmware on the core): "
          f"{records} coil records, {wakes} wakes")
    reference = None
    for quick in (True, False):
        name = "quick way" if quick else "long way (reference, quick = False)"
        per: dict[str, list[tuple[float, float]]] = {}
        whole = []
        for _ in range(3):
            out, ns, _ = replay(walter_inputs, quick, timed=True)
            reference = reference or out
            assert out == reference, "the quick way and the long way gave different outcomes"
            for k, xs in ns.items():
                per.setdefault(k, []).append((statistics.mean(xs) / 1e3, statistics.median(xs) / 1e3))
            whole.append(replay(walter_inputs, quick, timed=False)[2] / records * 1e6)
        counts = {k: len(v) for k, v in ns.items()}
        print(f"{name}:")
        for k, runs in per.items():
            mean = statistics.median(m for m, _ in runs)
            median = statistics.median(m for _, m in runs)
            print(f"  {k:<21} {counts[k]:>6} records: mean {mean:6.1f} us, median {median:5.1f} us a "
                  f"record (median of 3 runs) target <= {TARGET_US:.0f} us: "
                  f"{'met' if mean <= TARGET_US else 'MISSED'} by the mean")
        print(f"  whole judge (changes and wakes, CPU): {statistics.median(whole):.1f} us a record "
              f"(min-max of 3 {min(whole):.1f}-{max(whole):.1f})", flush=True)

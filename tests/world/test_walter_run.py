"""``hexbench run SCEN`` on the paper's figure scenarios and generated goals (issue 49 item 4),
with the planner the scenario names (``planner = "walter"``) and the Python model: the run
holds the fleet to the round model round by round (it stops at the first round that differs,
naming the modules), so a run that reaches the goal in the model's number of rounds moved as
the model says. Recorded, and the recording replays. Inadmissible figures are refused in one
line before anything moves."""

from __future__ import annotations

from pathlib import Path

import pytest

from bus.lattice import Cell
from bus.scenario import load
from hexbench.cli import main
from planner_svc.planners.walter import choose
from planner_svc.planners.walter.goals import generate
from recordings.reader import iter_samples


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["run", *argv, "--program", "model", "--isolated"])
    out = capsys.readouterr()
    return code, out.out, out.err


def predicted_rounds(goal, initial) -> int:
    model = choose(goal, sorted(initial)).model()
    model.run()
    return len(model.rounds)


def held_to_the_model(code: int, out: str, rounds: int) -> None:
    summary = [line for line in out.splitlines() if line.startswith("walter: ")]
    assert code == 0 and summary, out[-1500:]
    assert summary[-1].startswith(f"walter: goal reached in {rounds} rounds"), summary[-1]


@pytest.mark.parametrize("name", ["walter-fig3", "walter-fig5a", "walter-fig8", "walter-fig9"])
def test_a_figure_scenario_runs_walter_by_itself_as_the_round_model_says(name, capsys):
    sc = load(name)
    assert sc.planner == "walter"
    code, out, _ = run(capsys, name)  # no --planner: the scenario's
    assert "planner walter" in out and "] round   1 moves" in out  # progress in rounds
    held_to_the_model(code, out, predicted_rounds(sc.goal, sc.initial))


def test_figure_5b_is_refused_before_anything_moves(capsys):
    code, out, err = run(capsys, "walter-fig5b")
    assert code == 2 and "bring-up" not in out and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hexbench run: error: planner walter: inadmissible goal")
    assert "not one contiguous north-south chain" in lines[0]


def _scenario_file(tmp: Path, name: str, goal: frozenset[Cell], chain: list[Cell]) -> Path:
    """G and I (free end first, the anchor last and fixed); orientations vary so that every
    side a module names goes through its own body frame."""
    cells = lambda cs: ", ".join(f"[{c.x}, {c.y}]" for c in cs)  # noqa: E731
    mods = "".join(f"[[modules]]\nid = {i + 1}\ncell = [{c.x}, {c.y}]\norientation = {(5 * i) % 6}\n"
                   for i, c in enumerate(chain))
    path = tmp / f"{name}.toml"
    path.write_text(f'name = "{name}"\nplanner = "walter"\nfixed = [{chain[-1].x}, {chain[-1].y}]\n'
                    f"goal = [{cells(sorted(goal))}]\n{mods}")
    return path


@pytest.mark.parametrize("n,cost_class,seed", [
    (6, "0", 3), (6, "1", 3), (6, ">1", 3), (12, "1", 3), (20, ">1", 1),
    # position 9 is passed by position 6 without being its substrate (6 asks it only to open a
    # pin): counting only substrate requests, it took position 8 and went CW in round 33
    (11, "0", 1)])
def test_a_generated_goal_is_reached_as_the_round_model_says(n, cost_class, seed, tmp_path, capsys):
    gen = generate(n, cost_class, seed=seed)
    assert gen.choice.candidate.cost_class == cost_class
    path = _scenario_file(tmp_path, f"generated-{n}-{cost_class.replace('>', 'gt')}", gen.goal,
                          gen.choice.chain)
    code, out, _ = run(capsys, str(path))
    held_to_the_model(code, out, predicted_rounds(gen.goal, gen.choice.chain))


def test_a_walter_run_is_recorded_and_replays(tmp_path, capsys):
    mcap = tmp_path / "fig3.mcap"
    code, out, _ = run(capsys, "walter-fig3", "--record", str(mcap))
    assert code == 0, out[-1500:]
    completed = [s for s in iter_samples(mcap) if s.topic.endswith("world/event")
                 and s.json()["kind"] == "move-completed"]
    summary = [line for line in out.splitlines() if line.startswith("walter: goal reached")][-1]
    assert f"moves {len(completed)} (planned {len(completed)})" in summary
    assert main(["replay", str(mcap), "--rrd", str(tmp_path / "fig3.rrd")]) == 0


@pytest.mark.parametrize("program", ["model", "firmware"])
def test_more_modules_than_a_module_holds_are_refused_before_boot(program, tmp_path, capsys):
    """Each module holds the goal table (bus.codec.WALTER_TABLE_CAPACITY entries, the C
    table's size): a larger fleet is refused in one line naming the limit, before anything
    boots, whichever program the modules would run."""
    from bus.codec import WALTER_MAX_MODULES, WALTER_TABLE_CAPACITY
    from planner_svc.rounds import beyond_the_modules

    n = WALTER_MAX_MODULES + 1
    chain = [Cell(-k, 0) for k in range(n - 1, -1, -1)]  # the free end first, the anchor (0, 0)
    goal = frozenset(Cell(k, 0) for k in range(n))
    path = _scenario_file(tmp_path, "too-many", goal, chain)
    code = main(["run", str(path), "--program", program, "--isolated"])
    out = capsys.readouterr()
    assert code == 2 and "Traceback" not in out.err
    assert out.out == ""  # nothing booted, nothing said
    assert out.err.strip().splitlines() == [
        f"hexbench run: error: planner walter: {n} modules, but a module holds a problem of at "
        f"most {WALTER_MAX_MODULES} (its goal table: {WALTER_TABLE_CAPACITY} entries)"]
    assert beyond_the_modules(WALTER_MAX_MODULES) is None  # the limit itself runs


def test_the_planner_service_refuses_it_before_bring_up(tmp_path):
    """The same limit where the planner runs in its own process (``hexbench planner``): the
    run ends before the PC sends a frame."""
    from bus import Bus
    from bus.clock import VirtualClock
    from bus.codec import WALTER_MAX_MODULES
    from bus.session import SessionOptions
    from planner_svc.service import PlannerService

    n = WALTER_MAX_MODULES + 1
    chain = [Cell(-k, 0) for k in range(n - 1, -1, -1)]
    scenario = load(str(_scenario_file(tmp_path, "too-many", frozenset(Cell(k, 0) for k in range(n)), chain)))
    bus = Bus(VirtualClock(), "too-many", options=SessionOptions(isolated=True))
    try:
        sent: list[bytes] = []
        bus.subscribe(bus.keys.frames, lambda k, p: sent.append(p))
        result = PlannerService(bus, scenario, "walter", say=lambda s: None).run()
    finally:
        bus.close()
    assert not result.ok and result.reason.startswith(f"walter: {n} modules, but a module holds")
    assert sent == []

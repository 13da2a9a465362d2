"""What the protocol can name (bus.scenario.Reach, bus.codec.COORD_LIMIT): cells relative to the
fixed module, in its frame, within -127..127 (v2) or -99..99 (thesis-2009). A scenario whose
start or goal leaves it, or a plan that does, is refused in one line before the fleet boots;
absolute coordinates are free (the issue: thesis-6 120 cells from the origin was refused, a
101-module line 100 cells from its fixed module was taken and died at Localize step 100)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bus.lattice import Cell, offset_in_frame, rotate_offset
from bus.scenario import Reach, ScenarioError, load, loads, override


def line(n: int, fixed_x: int, profile: str = "v2", extra: str = "") -> str:
    cells = [[fixed_x + k, 0] for k in range(n)]
    return f'name = "line{n}"\nprofile = "{profile}"\nfixed = [{fixed_x}, 0]\ninitial = {cells}\n{extra}'


def shifted_thesis_6(dx: int, dy: int, profile: str = "v2") -> str:
    sc = load("thesis-6")
    cells = [[c.x + dx, c.y + dy] for c in sc.initial]
    goal = [[c.x + dx, c.y + dy] for c in sc.goal]
    return (f'name = "thesis-6-far"\nprofile = "{profile}"\nfixed = [{sc.fixed.x + dx}, {sc.fixed.y + dy}]\n'
            f"initial = {cells}\ngoal = {goal}\n")


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_a_fleet_far_from_the_origin_is_taken(profile):
    """Absolute coordinates are not carried: thesis-6 shifted by (+120, -120) (refused before)."""
    sc = loads(shifted_thesis_6(120, -120, profile))
    assert sc.fixed == Cell(121, -120) and len(sc.modules) == 6


def test_a_101_module_line_fits_v2_and_not_the_thesis():
    """x = -1..99 from fixed [-1, 0]: 100 cells from the reference. v2 carries it; the thesis's
    two MSG1 digits do not, and it says so at the cell, in one line (taken before)."""
    assert len(loads(line(101, -1)).modules) == 101
    with pytest.raises(ScenarioError) as exc:
        loads(line(101, -1, "thesis-2009"), source="line.toml")
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("line.toml: line 4, ")
    assert "cell [99, 0] is (100, 0) from the fixed module [-1, 0]" in msg and "-99..99" in msg


def test_128_cells_from_the_fixed_module_is_refused_in_v2():
    with pytest.raises(ScenarioError, match=r"cell \[128, 0\] is \(128, 0\) .*v2 carries -127\.\.127"):
        loads(line(129, 0))
    # the goal too, where the start fits ((127, 1) is 128 steps away, but (127, 1) in x, y)
    start = [[k, 0] for k in range(128)] + [[127, 1]]
    goal = [[k, 0] for k in range(129)]
    with pytest.raises(ScenarioError, match=r"line 3, the goal leaves .*cell \[128, 0\]"):
        loads(f"fixed = [0, 0]\ninitial = {start}\ngoal = {goal}\n")


def test_the_profile_given_on_the_command_line_is_held_to_its_range():
    sc = loads(line(101, -1))
    with pytest.raises(ScenarioError, match=r"--profile thesis-2009: the fleet .* -99\.\.99"):
        override(sc, profile="thesis-2009")
    assert override(loads(shifted_thesis_6(120, -120)), profile="thesis-2009").profile == "thesis-2009"


def test_the_range_is_counted_in_the_reference_frame():
    """A reference turned by one side: (100, 28) is (-28, 128) in its frame (beyond), though
    100 and 28 both fit: the reach follows the frame MSG1 and POS use."""
    assert Reach(Cell(0, 0), 0, "v2").beyond(Cell(100, 28)) is None
    assert "(-28, 128)" in Reach(Cell(0, 0), 1, "v2").beyond(Cell(100, 28))


@given(x=st.integers(-300, 300), y=st.integers(-300, 300), rx=st.integers(-300, 300),
       ry=st.integers(-300, 300), o=st.integers(0, 5))
def test_offset_in_frame_is_what_the_bring_up_turns_back(x, y, rx, ry, o):
    """The bring-up turns a report into a global cell with rotate_offset(report, o) + fixed."""
    dx, dy = offset_in_frame(Cell(x, y), Cell(rx, ry), o)
    gx, gy = rotate_offset((dx, dy), o)
    assert (rx + gx, ry + gy) == (x, y)


def test_a_plan_that_leaves_the_range_is_refused_before_the_fleet_boots(tmp_path, capsys):
    """A line 0..127 and a module on top at 126 going under at 127: start and goal fit, but
    thesis-serial walks it round the end through x = 128. 'hexbench run' refuses it in one line
    before anything opens (exit 2, nothing booted); 'hexbench plan' prints it and says so."""
    from hexbench.cli import main

    row = [[x, 0] for x in range(128)]
    p = tmp_path / "edge.toml"
    p.write_text(f'name = "edge"\nfixed = [0, 0]\ninitial = {row + [[126, 1]]}\ngoal = {row + [[127, -1]]}\n')
    assert main(["run", str(p), "--planner", "thesis-serial"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert ("planner thesis-serial: the plan leaves what the protocol can name at step 2, "
            "(127,1) -> (128,0): cell [128, 0] is (128, 0)") in err
    assert main(["plan", str(p), "--planner", "thesis-serial"]) == 1
    out, err = capsys.readouterr()
    assert "goal reached" in out and err.count("\n") == 1 and "(128,0)" in err


@pytest.mark.parametrize("program", ["model", "firmware"])
def test_thesis_6_120_cells_from_the_origin_runs_to_the_goal(tmp_path, capsys, program):
    """Refused before (absolute coordinates held to -99..99); every module is localized in
    the reference's frame and turned back into the scenario's cells."""
    from hexbench.cli import main

    p = tmp_path / "far.toml"
    p.write_text(shifted_thesis_6(120, -120))
    assert main(["run", str(p), "--program", program]) == 0
    out = capsys.readouterr().out
    assert "localized 6 of 6 modules" in out and out.strip().splitlines()[-1].startswith(
        "thesis-serial: goal reached; steps 8, moves 8")


@pytest.mark.slow
def test_a_101_module_line_runs_to_the_goal_100_cells_from_its_reference(tmp_path, capsys):
    """Fixed [-1, 0], x = -1..99 (the issue's line: the model died at Localize step 100, the C
    told m101 it sat on the reference's cell); the far end then moves. The C firmware on the
    fleet core: ~47 s wall on a loaded 2-core machine."""
    from hexbench.cli import main

    goal = [[x, 0] for x in range(-1, 99)] + [[98, 1]]
    p = tmp_path / "line.toml"
    p.write_text(line(101, -1, extra=f"goal = {goal}\n"))
    assert main(["run", str(p), "--program", "firmware"]) == 0
    out = capsys.readouterr().out
    assert "could not be localized" not in out and "101 modules read back" in out
    assert "moved (99,0)->(98,1)" in out and out.strip().splitlines()[-1].startswith(
        "thesis-serial: goal reached; steps 1, moves 1")

"""The planner service end to end on a virtual fleet: ``hexbench run`` (issue: planner service)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from hexbench.cli import main
from bus.lattice import Direction, Side
from bus.scenario import load
from planner_svc import planners
from planner_svc.script import ScriptError, parse_script
from processes import free_port

ROOT = Path(__file__).resolve().parents[2]


def run(capsys, *argv: str) -> tuple[int, str]:
    code = main(["run", *argv])
    return code, capsys.readouterr().out


@pytest.mark.parametrize("scenario,planner,moves", [
    ("thesis-6", "thesis-serial", 8),
    ("thesis-6", "thesis-parallel", 8),
    ("thesis-6-reverse", "complete", None),  # the thesis planner stalls on this one
])
def test_run_reaches_the_goal(capsys, scenario, planner, moves):
    code, out = run(capsys, scenario, "--planner", planner, "--clock", "virtual")
    assert code == 0, out
    last = out.strip().splitlines()[-1]
    assert last.startswith(f"{planner}: goal reached")
    assert moves is None or f"moves {moves} " in last
    assert "localized 6 of 6 modules in 3 Localize step(s)" in out  # bring-up over the bus
    assert "goal 6/6" in out


def test_run_says_why_the_thesis_planner_stalls(capsys):
    code, out = run(capsys, "thesis-6-reverse", "--planner", "thesis-serial")
    assert code == 1
    assert "FAILED: planner thesis-serial stopped: no more possible motion" in out


def _first_move(scenario_name: str, planner: str):
    sc = load(scenario_name)
    mv = planners.get(planner).plan(sc).steps[0][0]
    mobile = sc.module_at(mv.mobile)
    sub = sc.module_at(mv.substrate)
    return sc, mv, mobile, sub


def test_sabotaged_move_stops_with_a_diagnosis(capsys):
    """The substrate's negative relay on the side facing the mobile is stuck off: the
    run stops at the first move, naming the module, the move and the world's reason."""
    sc, mv, mobile, sub = _first_move("thesis-6", "thesis-serial")
    j = int(mv.joint)
    toward = j if mv.direction is Direction.CW else j - 1
    repel_body = Side.of(toward + 3 - sub.orientation)
    fault = f"m{sub.id}.S{int(repel_body)}-:off"
    code, out = run(capsys, "thesis-6", "--planner", "thesis-serial", "--fault", fault)
    assert code == 1
    last = out.strip().splitlines()[-1]
    assert f"move m{mobile.id} {mv.mobile}->{mv.goal}" in last
    assert "move-refused wrong-polarity" in last
    assert f"substrate m{sub.id} body side {int(repel_body)} facing the mobile is off" in last
    assert "moves 0 " in last


def test_script_planner_drives_a_module(capsys, tmp_path):
    script = tmp_path / "wiggle.txt"
    script.write_text("# open and close a joint of module 2, then read its location\n"
                      "select 2\nsend JxOpen 3\nexpect ack 1\nwait 0.5\n"
                      "send 2 3   # JxClose by code\nexpect ack 2\n"
                      "send Report\nexpect position id=2\n")
    code, out = run(capsys, "pair", "--planner", f"script:{script}")
    assert code == 0, out
    assert "script wiggle.txt:9: expect position id=2" in out


def test_script_errors_name_the_line(tmp_path):
    with pytest.raises(ScriptError, match=r"s.txt:2: 'send Nope 1': no function named 'Nope'"):
        parse_script("select 1\nsend Nope 1\n", "s.txt")
    with pytest.raises(ScriptError, match="unknown action 'jump'"):
        parse_script("jump 3\n", "s.txt")


def test_failed_expectation_in_a_script_fails_the_run(capsys, tmp_path):
    script = tmp_path / "bad.txt"
    script.write_text("select 1\nsend SxP 3\nexpect ack 99 timeout=2\n")
    code, out = run(capsys, "pair", "--planner", f"script:{script}")
    assert code == 1
    assert "bad.txt:3: 'expect ack 99 timeout=2' failed" in out


def test_thesis_profile_fleet_is_refused_with_the_reason(capsys):
    code, out = run(capsys, "thesis-6", "--profile", "thesis-2009")
    assert code == 1
    assert "taking the initial configuration from scenario 'thesis-6'" in out
    assert "thesis-2009 modules have no addressing" in out


@pytest.mark.slow
@pytest.mark.wall_clock
def test_planner_in_another_process_reaches_the_goal(tmp_path):
    """Acceptance: ``hexbench fleet thesis-6 --clock wall`` in one process and ``hexbench
    planner thesis-6 --clock wall`` in another, over zenoh on loopback."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    fleet_name = f"mp{os.getpid()}"
    port = free_port()
    fleet = subprocess.Popen([sys.executable, "-m", "hexbench", "fleet", "thesis-6", "--clock", "wall",
                              "--fleet", fleet_name, "--listen", f"tcp/127.0.0.1:{port}"],
                             cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    try:
        line = fleet.stdout.readline()  # the fleet says it is up before the planner starts
        assert "fleet thesis-6" in line, line
        planner = subprocess.run([sys.executable, "-m", "hexbench", "planner", "thesis-6", "--planner",
                                  "thesis-parallel", "--clock", "wall", "--fleet", fleet_name,
                                  "--connect", f"tcp/127.0.0.1:{port}"],
                                 cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert planner.returncode == 0, planner.stdout + planner.stderr
        assert "thesis-parallel: goal reached" in planner.stdout
    finally:
        fleet.terminate()
        fleet.wait(timeout=30)


def test_the_documented_example_script_moves_the_pair(capsys):
    """docs/scripts/pair-rotate.txt: Ref, one Localize step, a v2 Move, Report confirms."""
    code, out = run(capsys, "pair", "--planner", f"script:{ROOT / 'docs/scripts/pair-rotate.txt'}")
    assert code == 0, out
    assert "script finished; the world is at the goal" in out.strip().splitlines()[-1]


def test_bring_up_says_where_it_is(capsys):
    """A wall-clock bring-up takes minutes: each phase prints a line with its sim time."""
    from hexbench.cli import main

    assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual"]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith("bring-up:")]
    assert [line.split(":")[1].split()[0] for line in lines][:5] == ["boot", "m1", "Localize", "2",
                                                                     "localized"]
    assert "m1 is the reference at" in out and "1 ring(s) around it" in out
    assert "Localize step 1 of 1 done at" in out and "2 modules read back at" in out

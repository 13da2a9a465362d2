"""Progress of a run: moves n/N in the planner's lines, a bar under them on a terminal (read
through a real pseudo-terminal), plain lines in a pipe; the bus carries the plan's size."""

from __future__ import annotations

import io
import re

from bus.messages import PlannerProgress
from hexbench.cli import main
from hexbench.progress import Progress
from processes import run_in_pty


def test_plain_output_counts_moves_of_the_plan(capsys):
    assert main(["run", "thesis-6", "--planner", "complete", "--clock", "virtual"]) == 0
    out = capsys.readouterr().out
    planned = int(re.search(r"^plan: .* moves (\d+),", out, re.M).group(1))
    counts = re.findall(r"^\[ *[\d.]+ s\] step +\d+ moves +(\d+)/(\d+) ", out, re.M)
    assert planned > 1 and [int(n) for n, _ in counts][-1] == planned
    assert {int(total) for _, total in counts} == {planned}
    assert "\x1b[" not in out  # no terminal codes in a pipe


def test_a_terminal_gets_a_bar_of_moves():
    """Under a pseudo-terminal the run draws rich's bar (moves n/N, time left) and clears it
    before the summary; the lines still come as they happen."""
    code, screen = run_in_pty(["run", "thesis-6", "--planner", "complete", "--clock", "virtual"])
    assert code == 0
    text = screen.decode("utf-8", "replace")
    assert re.search(r"moves \(step \d+\).*\d+/\d+", text)  # the bar's text and its n/N column
    assert "\x1b[2K" in text  # lines drawn over the bar, which is redrawn below them
    assert "goal reached; steps" in text.splitlines()[-1] or "goal reached; steps" in text


def test_plain_progress_lines_are_rate_limited():
    out = io.StringIO()
    with Progress(stream=out, bar=False) as p:
        for i in range(1, 101):
            p.update("frames replayed", i, 100)
    lines = out.getvalue().splitlines()
    assert lines[0] == "progress: frames replayed 1/100" and lines[-1] == "progress: frames replayed 100/100"
    assert len(lines) == 2  # the first, then nothing new for 5 s but the end


def test_the_plan_size_travels_on_the_bus():
    p = PlannerProgress(1, 2, 3, 4, 5, "moved", planned=18)
    assert PlannerProgress.from_json(p.to_json()).planned == 18
    assert PlannerProgress.from_dict({"sim_time_ns": 1, "step": 2, "moves": 3, "goal_filled": 4,
                                      "goal_total": 5}).planned == 0  # older recordings


def test_replay_reports_its_phases(tmp_path, capsys):
    """``replay --rrd`` says what it is doing (plain lines off a terminal)."""
    from hexbench.cli import main as cli
    rec = tmp_path / "pair.mcap"
    assert cli(["run", "pair", "--clock", "virtual", "--record", str(rec)]) == 0
    capsys.readouterr()
    assert cli(["replay", str(rec), "--rrd", str(tmp_path / "pair.rrd")]) == 0
    err = capsys.readouterr().err
    assert "progress: replay: reading" in err
    n = int(re.search(r"progress: replay: drawing (\d+)/\1", err).group(1))
    assert f"{n} samples" in err

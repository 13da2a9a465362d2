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


def _rows(drawn: str, columns: int) -> list[str]:
    """What a terminal ``columns`` wide shows after ``drawn`` (scrollback included): text,
    carriage return, line feed, auto-wrap, and the few sequences rich uses (cursor up, erase
    line, colours, cursor on/off); any other sequence fails the test rather than being misread."""
    rows, row, col = [[]], 0, 0
    for token in re.findall(r"\x1b\[[0-9;?]*[A-Za-z]|[\r\n]|[^\x1b\r\n]", drawn):
        if token == "\r":
            col = 0
        elif token == "\n":
            row += 1
        elif token.startswith("\x1b["):
            args, op = token[2:-1], token[-1]
            if op == "A":
                row = max(0, row - int(args or 1))
            elif op == "K":  # erase to the end of the line, or (2) all of it
                assert args in ("", "0", "2"), f"unexpected {token!r}"
                rows[row] = [] if args == "2" else rows[row][:col]
            else:
                assert op == "m" or token in ("\x1b[?25l", "\x1b[?25h"), f"unexpected {token!r}"
            continue
        else:
            if col == columns:  # a character past the margin wraps to the next row
                row, col = row + 1, 0
            while len(rows) <= row:
                rows.append([])
            line = rows[row]
            line.extend(" " * (col - len(line)))
            line[col:col + 1] = [token]
            col += 1
        while len(rows) <= row:
            rows.append([])
    return ["".join(r).rstrip() for r in rows]


def test_a_terminal_gets_a_bar_of_moves():
    """Under a pseudo-terminal the run draws rich's bar (moves n/N, time left) and clears it
    before the summary; the lines still come as they happen."""
    columns = 120
    code, screen = run_in_pty(["run", "thesis-6", "--planner", "complete", "--clock", "virtual"],
                              columns=columns)
    assert code == 0
    text = screen.decode("utf-8", "replace")
    assert re.search(r"moves \(step \d+\).*\d+/\d+", text)  # the bar's text and its n/N column
    assert "\x1b[2K" in text  # lines drawn over the bar, which is redrawn below them
    # What the terminal shows at the end: every planner line, no trace of the bar anywhere
    # (each drawing was erased before a line took its place, the last before the summary),
    # and the summary last.
    rows = [r for r in _rows(text, columns) if r]
    assert not [r for r in rows if "moves (step" in r or "━" in r]
    summary = next(n for n, r in enumerate(rows) if r.startswith("complete: goal reached; steps"))
    assert len(rows) - summary == -(-len("".join(rows[summary:])) // columns)  # itself, wrapped
    assert re.fullmatch(r"\[ *[\d.]+ s\] step +\d+ moves +(\d+)/\1 .* complete: goal reached", rows[summary - 1])


def test_a_walter_run_shows_its_progress_in_rounds():
    """A Walter run beats lockstep rounds (many modules move in one): on a terminal the bar
    names the round, as the planner's lines do, and never a step."""
    columns = 120
    code, screen = run_in_pty(["run", "walter-4", "--planner", "walter", "--clock", "virtual"],
                              columns=columns)
    text = screen.decode("utf-8", "replace")
    assert code == 0, text[-2000:]
    drawn = re.findall(r"moves \(round (\d+)\).*?(\d+)/12", text)  # the bar: its text, moves n/N
    assert drawn and int(drawn[-1][0]) >= 9, drawn  # it follows the rounds (10 in all)
    assert "(step" not in text
    rows = [r for r in _rows(text, columns) if r]
    rounds = [int(n) for n in re.findall(r"^\[ *[\d.]+ s\] round +(\d+) moves", "\n".join(rows), re.M)]
    assert rounds[:3] == [1, 2, 3] and rounds[-1] == 10
    assert not [r for r in rows if re.match(r"\[ *[\d.]+ s\] step ", r)]


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

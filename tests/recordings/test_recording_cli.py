"""``hexbench info`` over a recording."""

from __future__ import annotations

import json

from hexbench.cli import main


def test_info_json_counts(recorded, capsys):
    assert main(["info", str(recorded.path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames_by_link"] == recorded.published.frames_by_link()
    assert info["complete"] is True
    assert info["noise"] == sum(1 for e in recorded.published.frames if e.kind == "noise") > 0
    assert info["faults"] == 1
    assert info["errors"] == recorded.tally.errors > 0
    assert info["metadata"]["scenario"] == "synthetic"
    assert info["duration_s"] == recorded.published.end_ns / 1e9


def test_info_text(recorded, capsys):
    assert main(["info", str(recorded.path)]) == 0
    out = capsys.readouterr().out
    assert "frames:" in out and "side" in out and "scenario" in out


def test_info_missing_file(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.mcap")]) == 2
    assert "no recording" in capsys.readouterr().err


def test_info_tells_the_boot_handshake_from_errors(tmp_path, capsys):
    """The control board repeats 'R' on UART0 while the comm board blinks: those overruns are
    a healthy boot, and info says so instead of counting them as errors."""
    out = tmp_path / "pair.mcap"
    assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual",
                 "--record", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    expected = int(text.split("expected:   uart-overrun ")[1].split()[0])
    assert expected > 0 and "boot handshake" in text
    frames_line = next(line for line in text.splitlines() if line.startswith("frames:"))
    assert f"(and {expected} expected)" in frames_line

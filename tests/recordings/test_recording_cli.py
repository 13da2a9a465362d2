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

"""``make demo``'s job: thesis-6 recorded and replayed, and how to open both in rerun and in
Foxglove; nothing is written into the packages."""

from __future__ import annotations

from pathlib import Path

from hexbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("bus", "module_sim", "planner_svc", "hil", "recordings", "hexbench", "firmware")


def _package_files() -> set[Path]:
    return {p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts and "build" not in p.parts}


def test_demo_says_how_to_open_the_run_in_rerun_and_foxglove(tmp_path, capsys):
    before = _package_files()
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "thesis-6.mcap").stat().st_size > 0 and (tmp_path / "thesis-6.rrd").stat().st_size > 0
    assert f"rerun {tmp_path / 'thesis-6.rrd'}" in out
    assert f"Foxglove: Open local file -> {(tmp_path / 'thesis-6.mcap').resolve()}" in out
    assert "foxglove/scene" in out and "--live foxglove" in out and "--live rerun" in out
    assert _package_files() == before

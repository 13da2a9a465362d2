"""Shared fixtures: one synthetic run recorded to MCAP (a private bus, a virtual clock)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from recordings.recorder import Recorder
from recordings.stats import Tally
from recordings.synthetic import Published, run_synthetic

FLEET = "rectest"


@dataclass
class Recorded:
    path: Path
    published: Published
    tally: Tally


def record_synthetic(path: Path, fleet: str = FLEET, recorder_kwargs: dict | None = None,
                     **run_kwargs) -> Recorded:
    """Run the synthetic run with a recorder attached; return what was published and written."""
    rec = Recorder(path, fleet=fleet, meta={"scenario": "synthetic", "seed": 1},
                   **(recorder_kwargs or {}))
    try:
        published = run_synthetic(fleet, attach=rec.attach, **run_kwargs)
    finally:
        tally = rec.close()
    return Recorded(path, published, tally)


@pytest.fixture(scope="session")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    return record_synthetic(tmp_path_factory.mktemp("rec") / "run.mcap", moves=6, filler_frames=12)


@pytest.fixture(scope="session")
def rerun_bin() -> str:
    exe = Path(sys.executable).with_name("rerun")
    if not exe.exists():
        pytest.skip("rerun CLI not installed next to the interpreter")
    return str(exe)


@pytest.fixture(scope="session")
def record():
    """``record(path, **run_kwargs) -> Recorded`` for tests that need their own run."""
    return record_synthetic

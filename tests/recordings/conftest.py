"""Shared fixtures: one synthetic run recorded to MCAP (a private bus, a virtual clock)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from recordings.recorder import Recorder
from recordings.stats import Tally
from synthetic import Published, run_synthetic
from toolchain import missing

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
        missing("the rerun CLI next to the interpreter", "pip install -e . (rerun-sdk)")
    return str(exe)


@pytest.fixture(scope="session")
def record():
    """``record(path, **run_kwargs) -> Recorded`` for tests that need their own run."""
    return record_synthetic


# --- recordings of a virtual fleet (module_sim) driven by the PC endpoint -----------------------
#: The PC's script for the ``pair`` scenario: address module 2, then three control codes.
PAIR_COMMANDS = (("Select", 1, 2), ("SxP", 3), ("JxOpen", 2), ("SxOff", 3))
BOOTED_NS = 9_000_000_000  # both modules have said COMM. LISTENING (at ~8.1 s)


def record_pair(path: Path, *, scenario: str = "pair", seed: int | None = None) -> Path:
    """Record the ``pair`` scenario booting and acknowledging :data:`PAIR_COMMANDS`."""
    from bus.scenario import load
    from hexbench.virtual_run import VirtualRun, resolve_scenario

    sc = load(scenario) if seed is None else resolve_scenario(scenario, seed=seed)
    with VirtualRun(sc, record=path, argv=["test", "pair"]) as run:
        run.clock.run(until_ns=BOOTED_NS, timeout_s=60)
        for command in PAIR_COMMANDS:
            run.pc.ack(*command)
    return path


@pytest.fixture(scope="session")
def pair_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return record_pair(tmp_path_factory.mktemp("pair") / "pair.mcap")


@pytest.fixture(scope="session")
def pair_commands() -> tuple:
    return PAIR_COMMANDS


@pytest.fixture(scope="session")
def record_pair_run():
    """``record_pair_run(path, seed=None) -> path``: a fresh recording of the pair script."""
    return record_pair

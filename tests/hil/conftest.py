"""Fixtures for the hardware-in-the-loop tests: stand-ins behind real pseudo-terminals.

Everything runs on the wall clock at 300 baud (33 ms a byte), so boots (~8 s) and the
serial conformance runs overlap: the first test that needs a stand-in starts all of them,
and the conformance shards run as pytest subprocesses in the background while the bridge
tests run. The v2 shards' stand-ins have their debug UART1 on a second pty, given to the
suite with ``--hexbench-debug``, and each shard writes ``--junitxml``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import pytest

from hexbench.standin import StandIn

ROOT = Path(__file__).resolve().parents[2]
BOOT_TIMEOUT_S = 40.0
SHARD_TIMEOUT_S = 150.0

#: Conformance shards against serial targets: (profile, -k expression). Each gets its own
#: stand-in; together they are the whole suite for both profiles.
SHARDS = [
    ("v2", "unknown or garbage"),
    ("v2", "not (unknown or garbage)"),
    ("thesis-2009", "unknown or garbage"),
    ("thesis-2009", "not (unknown or garbage)"),
]


@dataclass
class Shard:
    profile: str
    select: str
    standin: StandIn
    junit: Path  # the run's --junitxml: per test, the properties the plugin records
    done: threading.Event = field(default_factory=threading.Event)
    returncode: int | None = None
    output: str = ""
    proc: subprocess.Popen | None = None

    def command(self) -> list[str]:
        debug = [f"--hexbench-debug=serial:{self.standin.debug_path}"] if self.standin.debug_path else []
        return [sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
                "--pyargs", "hexbench.conformance", "-k", self.select,
                f"--hexbench-target=serial:{self.standin.path}", f"--hexbench-profile={self.profile}",
                *debug, f"--junitxml={self.junit}"]

    def run(self) -> None:
        """Wait for the module to boot, then run the suite against it (background thread)."""
        try:
            self.standin.wait_booted(BOOT_TIMEOUT_S)
            self.proc = subprocess.Popen(self.command(), cwd=ROOT, stdout=subprocess.PIPE,
                                         stderr=subprocess.STDOUT, text=True,
                                         env={**os.environ, "PYTHONPATH": str(ROOT)})
            self.output, _ = self.proc.communicate(timeout=SHARD_TIMEOUT_S)
            self.returncode = self.proc.returncode
        except Exception as exc:  # reported by the test that reads the shard
            self.output += f"\n{type(exc).__name__}: {exc}"
            if self.proc is not None and self.proc.poll() is None:
                self.proc.kill()
                self.output += "\n" + (self.proc.communicate()[0] or "")
        finally:
            self.standin.close()  # a wall-clock module ticks 100 times a second: stop it now
            self.done.set()


@dataclass
class HilRig:
    bridge_standin: StandIn
    shards: list[Shard]
    shard_timeout_s: float = SHARD_TIMEOUT_S


def pytest_generate_tests(metafunc) -> None:
    ids = [f"{p}-{'rest' if s.startswith('not') else 'unknown+garbage'}" for p, s in SHARDS]
    if "shard_index" in metafunc.fixturenames:
        metafunc.parametrize("shard_index", range(len(SHARDS)), ids=ids)
    if "v2_shard_index" in metafunc.fixturenames:  # the shards whose stand-in reports actuators
        v2 = [n for n, (profile, _) in enumerate(SHARDS) if profile == "v2"]
        metafunc.parametrize("v2_shard_index", v2, ids=[ids[n] for n in v2])


@pytest.fixture(scope="session")
def hil_rig(tmp_path_factory) -> HilRig:
    """Start every stand-in at once (they boot in parallel) and the conformance shards."""
    d = tmp_path_factory.mktemp("hil")
    started: list[StandIn] = []
    try:
        bridge_standin = StandIn.on_pty(d / "ttyHEX", debug_link=d / "ttyDBG", profile="v2").start()
        started.append(bridge_standin)
        shards = []
        for n, (profile, select) in enumerate(SHARDS):
            # a v2 board's debug UART1 carries its actuator reports: what each test left on
            debug = d / f"ttyCONF{n}d" if profile == "v2" else None
            s = StandIn.on_pty(d / f"ttyCONF{n}", debug_link=debug, profile=profile).start()
            started.append(s)
            shards.append(Shard(profile, select, s, d / f"conformance{n}.xml"))
        threads = [threading.Thread(target=shard.run, daemon=True, name=f"conformance-{shard.profile}")
                   for shard in shards]
        for t in threads:
            t.start()
        yield HilRig(bridge_standin, shards)
    finally:
        for shard in locals().get("shards", []):
            if shard.proc is not None and shard.proc.poll() is None:
                shard.proc.kill()
        for s in started:
            s.close()
        # a shard thread still closing its stand-in's zenoh session when the interpreter
        # exits is torn down inside Rust and aborts the process: let them finish
        for t in locals().get("threads", []):
            t.join(timeout=BOOT_TIMEOUT_S)


@pytest.fixture(scope="module")
def standin(hil_rig: HilRig) -> Iterator[StandIn]:
    """A booted v2 stand-in (module 1) behind ``<tmp>/ttyHEX``, debug UART1 behind ``ttyDBG``;
    stopped after the module's tests (the rig is session-wide only to overlap the boots)."""
    hil_rig.bridge_standin.wait_booted(BOOT_TIMEOUT_S)
    yield hil_rig.bridge_standin
    hil_rig.bridge_standin.close()

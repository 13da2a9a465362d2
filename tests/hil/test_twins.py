"""Mixed fleets end to end: real boards (stand-ins on real pseudo-terminals, centre and debug
UART) are fleet members with twins in the world (module_sim/twin.py, docs/hil.md).

Every run is a ``hexbench run --clock wall`` in its own process with its stand-ins in theirs;
they all start together (the first test that needs one starts them all) and each test
waits for its own, so the suite pays for the longest (thesis-6: about 140 s), not the sum.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from mcap.reader import make_reader
from wall_clock import heard

pytestmark = pytest.mark.wall_clock  # tests/support/wall_clock.py

ROOT = Path(__file__).resolve().parents[2]
RUN_TIMEOUT_S = 400.0
PAIR = ('name = "pair-real"\nprofile = "v2"\nfixed = [0, 0]\ngoal = [[0, 0], [0, 1]]\n'
        "[[modules]]\nid = 1\ncell = [0, 0]\n[[modules]]\nid = 2\ncell = [1, 0]\n")


@dataclass
class Run:
    """One ``hexbench run`` with stand-ins for the modules in ``boards`` (id -> stand-in
    options), each on a pty for its centre channel and one for its debug UART."""

    name: str
    args: list[str]
    boards: dict[int, list[str]]
    debug: bool = True
    dir: Path = Path()
    standins: list[subprocess.Popen] = field(default_factory=list)
    proc: subprocess.Popen | None = None
    out: str = ""
    code: int | None = None

    def start(self, base: Path) -> None:
        self.dir = base / self.name
        self.dir.mkdir()
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        real = []
        for ident, extra in self.boards.items():
            link, dlink = self.dir / f"m{ident}", self.dir / f"m{ident}d"
            self.standins.append(subprocess.Popen(
                [sys.executable, "-m", "hexbench", "standin", "--pty", "--link", str(link),
                 "--debug-pty", str(dlink), "--module", str(ident), *extra],
                stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=env))
            real += ["--real", f"{ident}={link}" + (f",{dlink}" if self.debug else "")]
        deadline = time.monotonic() + 30
        for ident in self.boards:  # the bridges open the ptys by their links
            while not (self.dir / f"m{ident}d").exists():
                assert time.monotonic() < deadline, f"{self.name}: stand-in m{ident} has no pty"
                time.sleep(0.05)
        if "scenario.toml" in self.args:
            (self.dir / "scenario.toml").write_text(PAIR)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "hexbench", "run", *self.args, *real, "--clock", "wall",
             "--record", "run.mcap", "--isolated", "--fleet", self.name],
            cwd=self.dir, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)

    def wait(self) -> "Run":
        if self.code is None:
            try:
                self.out = heard(self.proc.communicate(timeout=RUN_TIMEOUT_S)[0])
                self.code = self.proc.returncode
            finally:
                self.proc.kill()
                for s in self.standins:
                    s.terminate()
                for s in self.standins:
                    s.wait(timeout=10)
        return self

    def records(self) -> list[tuple[str, dict]]:
        with open(self.dir / "run.mcap", "rb") as f:
            return [(ch.topic, json.loads(m.data)) for _, ch, m in make_reader(f).iter_messages()
                    if ch.message_encoding == "json"]  # not the foxglove/* channels

    def events(self, kind: str) -> list[dict]:
        return [d for t, d in self.records() if t.startswith("event/") and d["kind"] == kind]


RUNS = {
    # the fixed module real: its twin's side light localizes its virtual neighbours
    "fixed": Run("fixed", ["thesis-6", "--planner", "complete"], {2: []}),
    # a moving module real: moved, verified, its board's actuator reports checked
    "mobile": Run("mobile", ["thesis-6", "--planner", "complete"], {5: []}),
    # two real boards on two ports, four virtual modules
    "two": Run("two", ["thesis-6", "--planner", "complete"], {2: [], 5: []}),
    # a board that disagrees with its program once
    "wrong": Run("wrong", ["scenario.toml", "--planner", "thesis-serial"], {2: ["--wrong-ack", "3"]}),
    # a board that sends no actuator reports: the world follows its twin's body
    "silent": Run("silent", ["scenario.toml", "--planner", "thesis-serial"],
                  {2: ["--no-actuator-reports"]}),
    # only the centre channel bridged (no debug UART): likewise
    "centre": Run("centre", ["scenario.toml", "--planner", "thesis-serial"], {2: []}, debug=False),
    # the script planner drives a board that sends no reports, as it drives any module
    "script": Run("script", ["pair", "--planner", f"script:{ROOT}/docs/scripts/pair-rotate-real.txt"],
                  {2: ["--no-actuator-reports"]}),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Run]:
    base = tmp_path_factory.mktemp("twins")
    try:
        for run in RUNS.values():
            run.start(base)
        yield RUNS
    finally:
        for run in RUNS.values():
            if run.proc is not None and run.code is None:
                run.proc.kill()
            for s in run.standins:
                s.kill()


def _ok(run: Run) -> Run:
    run.wait()
    assert run.code == 0, run.out
    assert "goal reached" in run.out.splitlines()[-2], run.out
    return run


def test_fixed_real_module_reaches_the_goal_with_no_divergence(runs):
    run = _ok(runs["fixed"])
    recs = run.records()
    serial = [d for t, d in recs if t.startswith("frame/") and d["origin"] == "serial"]
    assert {d["src"] for d in serial} == {"hil.m2", "m2.ctrl"}
    assert {"position", "ack"} <= {d["kind"] for d in serial}
    # the board's answers and debug lines were held against its twin's, and agreed
    assert not run.events("twin-diverged"), run.out
    assert "twin check m2 (centre): " in run.out and "twin check m2 (debug): " in run.out
    assert run.out.count("no divergence") == 2, run.out
    # the twin's light, not the board's, localized the neighbours: every module localized
    assert "bring-up: localized 6 of 6 modules" in run.out


def test_moving_real_module_is_moved_by_the_world_and_checked(runs):
    run = _ok(runs["mobile"])
    recs = run.records()
    moved = [d for t, d in recs if t == "world/event" and d["kind"] == "move-completed"
             and d["module"] == "m5"]
    assert len(moved) == 2  # thesis-6 by `complete`: m5 moves twice
    assert not [d for t, d in recs if t == "world/event" and d["kind"] == "move-confirmed"]
    # the board reported its bits on its debug UART: they agree with its twin's, one for one
    reports = Counter(d["origin"] for t, d in recs if t == "frame/debug/m5.ctrl"
                      and d["kind"] == "actuators")
    assert reports["serial"] > 0 and reports["serial"] == reports["twin"]
    assert Counter(d["origin"] for t, d in recs if t == "world/actuators/m5")["serial"] == reports["serial"]
    assert not run.events("twin-diverged")
    # it could not localize itself beside virtual neighbours: its twin's report was used
    assert "m5 (real) is not localized on its board" in run.out
    assert [d["src"] for d in run.events("twin-view")] == ["m5"]


def test_two_real_boards_and_four_virtual_reach_the_goal(runs):
    run = _ok(runs["two"])
    serial = {d["src"] for t, d in run.records() if t.startswith("frame/") and d["origin"] == "serial"}
    assert serial == {"hil.m2", "hil.m5", "m2.ctrl", "m5.ctrl"}
    assert not run.events("twin-diverged")
    assert run.out.count("no divergence") == 4


def test_one_wrong_ack_is_exactly_one_divergence(runs):
    run = _ok(runs["wrong"])
    (ev,) = run.events("twin-diverged")
    # its answers: ACK of Select(m2), POS, ACK of Report, then the third ACK (answer 4)
    assert ev["src"] == "m2" and ev["link"] == "centre" and ev["index"] == 3
    assert ev["expected_kind"] == ev["received_kind"] == "ack"
    expected, received = bytes.fromhex(ev["expected"]), bytes.fromhex(ev["received"])
    # the same ACK but for one bit of its code byte (0a0d0a0d "M: " "ACK" code 0a0d)
    assert expected[:-3] == received[:-3] and expected[-3] ^ received[-3] == 0x20
    assert "twin diverged: m2: centre frame 4" in run.out
    assert "twin check m2 (centre): " in run.out and "1 differ: first m2: centre frame 4" in run.out


def test_a_board_without_actuator_reports_moves_by_its_twin(runs):
    run = _ok(runs["silent"])
    recs = run.records()
    origins = Counter(d["origin"] for t, d in recs if t == "world/actuators/m2")
    assert origins["twin"] > 0 and origins["serial"] == 0
    assert [d["module"] for t, d in recs if t == "world/event" and d["kind"] == "move-completed"] == ["m2"]
    assert not run.events("twin-diverged")


def test_a_board_with_only_its_centre_channel_bridged(runs):
    run = _ok(runs["centre"])
    assert "moves 1 " in run.out.splitlines()[-2]
    assert "m2 (real) is not localized on its board" in run.out
    assert "twin check m2 (centre): " in run.out and "(debug)" not in run.out
    serial, sources, actuators, moved = [], set(), set(), []
    for topic, d in run.records():
        if topic.startswith("frame/"):
            if d["origin"] == "serial":
                serial.append(d)
            else:  # the world's m2 frames are its twin's, marked so
                sources.add(d["src"])
                assert d["origin"] == ("twin" if d["src"].startswith("m2.") else "virtual")
        elif topic == "world/actuators/m2":
            actuators.add(d["origin"])
        elif topic == "world/event" and d["kind"] == "move-completed":
            moved.append(d)
    # the real module's answers came through the bridge, and only through it
    assert serial and {d["src"] for d in serial} == {"hil.m2"}
    assert {"position", "ack"} <= {d["kind"] for d in serial}
    assert {s for s in sources if s.startswith("m2.")} == {"m2.comm", "m2.ctrl"}
    assert actuators == {"twin"}
    (ev,) = moved
    assert ev["module"] == "m2" and ev["data"]["to"] == [0, 1]


def test_a_script_drives_a_board_without_reports_and_the_world_follows_its_twin(runs):
    run = runs["script"].wait()
    assert run.code == 0, run.out
    assert "script finished; the world is at the goal" in run.out
    recs = run.records()
    assert [d["module"] for t, d in recs if t == "world/event" and d["kind"] == "move-completed"] == ["m2"]
    assert Counter(d["origin"] for t, d in recs if t == "world/actuators/m2")["serial"] == 0
    assert not run.events("twin-diverged")

"""The modules' half of Walter, Tsai & Amato's distributed reconfiguration (docs/protocol.md,
"v2 distributed reconfiguration"), on the Python model: the PC localizes the fleet, hands it
the problem and beats the rounds; each module decides its moves (Figure 10), asks its
substrate and holders over the side IR links and rotates itself, and the world's physics
judges every move. No frame per move crosses the centre channel."""

from __future__ import annotations

import pytest

from bus.codec import Kind
from bus.lattice import Cell, Side
from bus.messages import Pose, WorldEvent
from bus.scenario import loads
from planner_svc.bringup import BringUp
from planner_svc.planners.walter import choose
from planner_svc.rounds import RoundDriver, WalterProblem, problem_of

from fleet_rig import FleetRig

#: I along the anchor's side 6: the anchor m1 at (0, 0), m2, m3 at the free end; G is the
#: column x = 0. Orientations other than the reference's, so every side and joint a module
#: names goes through its own body frame.
CHAIN3 = """
name = "walter-chain3"
profile = "v2"
program = "model"
fixed = [0, 0]
goal = [[0, 1], [0, 0], [0, -1]]
[[modules]]
id = 1
cell = [0, 0]
orientation = 0
[[modules]]
id = 2
cell = [-1, 0]
orientation = 3
[[modules]]
id = 3
cell = [-2, 0]
orientation = 5
"""
#: Position 0 (m3) rolls CW over the top into (0, 1) in three rounds (round the end of I,
#: into the groove, over the anchor); position 1 (m2) is free in round 3 (m3 has left the
#: groove beside it) and goes at once, CCW under the anchor into (0, -1). In round 3 both
#: turn about the anchor from two sides that meet at a joint: their repelling sides on
#: together would be a drive pair of the anchor's own, so the anchor turns the first to ask
#: (m2, window 3) at once and the second (m3, window 4) in the late slot. m2 and m3, side by
#: side in round 3, each open their own pin on the other.
CHAIN3_PROBLEM = WalterProblem(3, 2, 0, Cell(0, 0), ((Cell(0, 1), True, 0), (Cell(0, -1), False, 0)))
CHAIN3_MOVES = [(1, "m3", "CW", (-2, 1)), (2, "m3", "CW", (-1, 1)), (3, "m2", "CCW", (0, -1)),
                (3, "m3", "CW", (0, 1))]


class Rig(FleetRig):
    def __init__(self, toml: str) -> None:
        super().__init__("walter", loads(toml))
        self.events: list[WorldEvent] = []
        self.poses: dict[str, Pose] = {}
        self.frames: list = []
        root = self.bus.keys.root
        self.bus.subscribe(f"{root}/world/event", lambda k, p: self.events.append(WorldEvent.from_json(p)))
        self.bus.subscribe(f"{root}/world/pose/*", self._pose)
        self.bus.subscribe_frames(self.frames.append)
        self.said: list[str] = []
        self.fleet.power_up()
        BringUp(self.pc, self.scenario, say=self.said.append).run()
        self.driver = RoundDriver(self.pc, self.scenario, say=self.said.append)

    def _pose(self, key: str, payload: bytes) -> None:
        p = Pose.from_json(payload)
        self.poses[p.module] = p


def _run_problem(toml: str, problem: WalterProblem, limit: int = 8) -> Rig:
    rig = Rig(toml)
    rig.mark = len(rig.frames)
    rig.driver.upload(problem)
    rig.starts = []  # sim time of each round's end
    rig.result = rig.driver.run(limit, progress=lambda r, heard: rig.starts.append(rig.clock.now_ns()))
    return rig


def _run(toml: str, problem: WalterProblem) -> Rig:
    return _run_problem(toml, problem)


@pytest.fixture(scope="module")
def chain3():
    rig = _run(CHAIN3, CHAIN3_PROBLEM)
    yield rig
    rig.close()


def test_the_c_firmware_makes_the_same_frames(chain3):
    """The C firmware (host build) against the Python model: every frame on every wire, the
    same bytes at the same sim time, from power-up to the last round."""
    fw = _run(CHAIN3.replace('program = "model"', 'program = "firmware"'), CHAIN3_PROBLEM)
    try:
        def key(f):
            return f.link, f.src, f.raw, f.sim_time_ns
        model, firmware = [key(f) for f in chain3.frames], [key(f) for f in fw.frames]
        first = next((k for k, (a, b) in enumerate(zip(model, firmware)) if a != b), None)
        assert first is None and len(model) == len(firmware), (
            f"first difference at frame {first}: model {model[first] if first is not None else None}"
            f" firmware {firmware[first] if first is not None else None}; {len(model)} vs {len(firmware)}")
        assert fw.result == chain3.result
    finally:
        fw.close()


def _round_of(rig: Rig, t_ns: int) -> int:
    """The round a time falls in (rounds end when the driver's progress is called)."""
    return next(r for r, end in enumerate(rig.starts, 1) if t_ns <= end)


def test_the_fleet_reaches_its_goal_with_no_refused_move(chain3):
    kinds = [e.kind for e in chain3.events]
    assert "move-refused" not in kinds and "fault" not in kinds, [
        (e.kind, e.module, e.data.get("detail")) for e in chain3.events if e.kind != "move-started"]
    cells = {name: (p.x, p.y) for name, p in chain3.poses.items()}
    assert cells == {"m1": (0, 0), "m2": (0, -1), "m3": (0, 1)}


def test_moves_round_by_round(chain3):
    done = [(_round_of(chain3, e.sim_time_ns), e.module, e.data["direction"], tuple(e.data["to"]))
            for e in chain3.events if e.kind == "move-completed"]
    assert sorted(done) == sorted(CHAIN3_MOVES)


def test_the_pc_stops_at_the_first_silent_busy_slot(chain3):
    # both arrive in round 3: its busy slot is silent
    assert chain3.result.done and chain3.result.rounds == 3
    assert all(chain3.result.busy[:2]) and chain3.result.busy[2] == 0


def test_no_frame_per_move_crosses_the_centre_channel(chain3):
    """After the upload the PC sends one beat a round, nothing else."""
    pc = [f for f in chain3.frames[chain3.mark:] if f.link == "pc"]
    names = [f.view.get("name") for f in pc]
    beats = [n for n in names if n == "WalterBeat"]
    assert len(beats) == chain3.result.rounds
    assert set(names) == {"Select", "WalterSetup", "WalterGoal", "WalterBeat"}


def test_each_module_logs_every_round_on_its_debug_uart(chain3):
    logs = [f for f in chain3.frames[chain3.mark:] if f.kind == Kind.WALTER_LOG.value]
    by_module: dict[str, list[dict]] = {}
    for f in logs:
        by_module.setdefault(f.src.split(".")[0], []).append(f.view)
    assert sorted(by_module) == ["m1", "m2", "m3"]
    assert all(len(v) == chain3.result.rounds for v in by_module.values())
    m3, m2 = by_module["m3"], by_module["m2"]
    assert [v["position"] for v in m3] == [0] * 3 and all(v["direction"] == "CW" for v in m3)
    assert [v["moved"] for v in m3] == [True, True, True] and m3[2]["stopped"]
    assert not any(v["unanswered"] for v in m3)
    # m2 waits in I while m3 rounds the end (which turns about it twice and is counted once),
    # is free in round 3 and goes CCW from position 1
    assert [v["free"] for v in m2] == [False, False, True]
    assert [v["moved"] for v in m2] == [False, False, True]
    assert m2[-1]["position"] == 1 and m2[-1]["direction"] == "CCW" and m2[2]["stopped"]
    assert all(v["anchor"] and not v["moved"] for v in by_module["m1"])


def test_the_flashed_images_make_the_same_frames_in_simavr(chain3):
    """The AVR images in simavr cores: every wire carries the model's frames, in the same
    order (times differ by design: each board's own tick grid and UBRR-exact baud rates,
    docs/firmware.md), and the world sees the same moves."""
    sim = _run(CHAIN3.replace('program = "model"', 'program = "simavr"'), CHAIN3_PROBLEM)
    try:
        def per_wire(rig):
            wires: dict[tuple[str, str], list[bytes]] = {}
            for f in rig.frames:
                wires.setdefault((f.link, f.src), []).append(f.raw)
            return wires
        model, flashed = per_wire(chain3), per_wire(sim)
        differ = [w for w in sorted(set(model) | set(flashed)) if model.get(w) != flashed.get(w)]
        assert not differ, f"wires that differ: {differ[:4]}"
        assert sim.result.rounds == chain3.result.rounds and sim.result.done
        moves = [(e.module, tuple(e.data["to"])) for e in sim.events if e.kind == "move-completed"]
        assert moves == [(e.module, tuple(e.data["to"])) for e in chain3.events
                         if e.kind == "move-completed"]
    finally:
        sim.close()


# --- held to the round model (planner_svc.planners.walter, the reference) ----------------------
def _scenario_of(choice, program: str) -> str:
    """I as the modules (m1 the free end, the anchor last and fixed), G the goal."""
    goal = ", ".join(f"[{g.x}, {g.y}]" for g in sorted(choice.goal))
    mods = "".join(f"[[modules]]\nid = {i + 1}\ncell = [{c.x}, {c.y}]\norientation = {(2 * i + 1) % 6}\n"
                   for i, c in enumerate(choice.chain))
    anchor = choice.chain[-1]
    return (f'name = "walter-held"\nprofile = "v2"\nprogram = "{program}"\n'
            f"fixed = [{anchor.x}, {anchor.y}]\ngoal = [{goal}]\n{mods}")


def _generated(n: int, cost_class: str, seed: int) -> list[Cell]:
    from planner_svc.planners.walter.goals import generate
    return sorted(generate(n, cost_class, seed).goal)


@pytest.mark.parametrize("program,goal", [
    ("model", [Cell(0, 0), Cell(1, 0), Cell(2, -1), Cell(1, 1)]),
    ("firmware", [Cell(0, 0), Cell(1, 0), Cell(2, -1), Cell(1, 1)]),
    ("firmware", _generated(12, "0", 5)),
    ("firmware", _generated(12, "1", 6)),
    ("firmware", _generated(12, ">1", 7)),
    ("firmware", _generated(11, "0", 1)),
], ids=["cost1-model", "cost1-firmware", "gen12-cost0", "gen12-cost1", "gen12-cost>1",
        "gen11-cost0-passed-by-a-holder"])
def test_the_fleet_moves_as_the_round_model_round_by_round(program, goal):
    """Which module, which direction, to which cell, in which round, as the round model says;
    no refusal; the PC stops in the round the model's last module arrives. A cost-1 goal (a
    bend in the substrate path, a column north of it), with both programs, and generated
    admissible goals of every path cost class."""
    choice = choose(goal)
    model = choice.model()
    model.run()
    rig = _run_problem(_scenario_of(choice, program), problem_of(choice, model), limit=len(model.rounds) + 3)
    try:
        bad = [(e.kind, e.module, e.data.get("detail")) for e in rig.events if e.kind in ("move-refused", "fault")]
        assert not bad
        position = {f"m{i + 1}": i for i in range(len(choice.chain))}
        fleet = sorted((_round_of(rig, e.sim_time_ns), position[e.module], e.data["direction"],
                        tuple(e.data["to"])) for e in rig.events if e.kind == "move-completed")
        expected = sorted((r.number, mv.module, mv.direction.value, (mv.to_cell.x, mv.to_cell.y))
                          for r in model.rounds for mv in r.moves)
        assert fleet == expected
        assert rig.result.done and rig.result.rounds == len(model.rounds)
    finally:
        rig.close()


def test_a_mover_that_only_asks_to_be_held_passes_too():
    """Figure 10 counts every module that passes one still in I, not only those that turn
    about it: a mover going by on the far side of the next module asks it only to open a pin
    (``hold``). Counted once, in the sense its goal table entry gives."""
    from bus.functions import WalterOp
    from module_sim.walter import Entry, WalterState

    w = WalterState(5, 2, 0, Cell(0, 0), table={k: Entry(Cell(k, 1), k % 2 == 0, 0) for k in range(4)})
    w.passed(WalterOp.PIVOT_CW, 0)
    w.passed(WalterOp.HOLD, 0)  # the same mover again: counted once
    w.passed(WalterOp.HOLD, 1)  # passes without turning about it (entry 1: CCW)
    w.passed(WalterOp.HOLD, 2)  # entry 2: CW
    assert (w.passed_cw, w.passed_ccw) == (2, 1)
    start = Cell(0, -3)  # in I, which runs south of the anchor; the cell beyond it is empty
    contacts = [start.neighbour(s) == Cell(0, -2) for s in Side]
    w.decide(1, start, contacts)
    assert w.free and w.position == 3


# --- hexbench run SCEN --planner walter ---------------------------------------------------------
def test_hexbench_run_planner_walter_reaches_the_goal_and_records_it(tmp_path):
    """Bring-up, the choice, the upload, one beat a round (held to the round model round by
    round), the world's verdict; recorded like every run (the default program: the C firmware
    on the fleet core)."""
    import subprocess
    import sys

    from recordings.reader import iter_samples

    mcap = tmp_path / "walter.mcap"
    r = subprocess.run([sys.executable, "-m", "hexbench", "run", "walter-4", "--planner", "walter",
                        "--record", str(mcap)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "goal reached in 10 rounds; steps 10, moves 12 (planned 12)" in r.stdout
    assert "round 10: 1 moved, every module in its goal" in r.stdout
    from bus.envelope import Envelope
    logs = [Envelope.from_json(smp.data) for smp in iter_samples(mcap) if smp.topic.startswith("frame/debug/")]
    logs = [e for e in logs if e.kind == Kind.WALTER_LOG.value]
    assert len(logs) == 4 * 10  # every module, every round


def test_an_inadmissible_goal_is_refused_before_anything_moves(tmp_path):
    import subprocess
    import sys

    bent = tmp_path / "bent.toml"
    bent.write_text('name = "bent"\nprofile = "v2"\nfixed = [0, 0]\ngoal = [[0, 0], [1, 0], [2, -1]]\n'
                    + "".join(f"[[modules]]\nid = {i}\ncell = [{x}, {y}]\n"
                              for i, (x, y) in enumerate([(-1, 1), (-1, 0), (0, 0)], 1)))
    r = subprocess.run([sys.executable, "-m", "hexbench", "run", str(bent), "--planner", "walter"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines() == [
        "hexbench run: error: planner walter: I is not a straight chain (section 4 assumes one)"]


def test_a_fault_on_a_movers_magnet_stops_the_fleet_naming_module_and_round():
    """m1 (the free end) cannot make its drive pair (S2 never energises): no move, no
    collision; the PC stops beating after the round and the run exits 1 naming both."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "hexbench", "run", "walter-4", "--planner", "walter",
                        "--fault", "m1.S2:off"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 1, r.stdout[-2000:] + r.stderr[-2000:]
    assert "FAILED: round 1: m1 did not move CW to (-3, 1), unlike the round model" in r.stdout
    assert "collision" not in r.stdout

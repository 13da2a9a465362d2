"""The modules' half of Walter, Tsai & Amato's distributed reconfiguration (docs/protocol.md,
"v2 distributed reconfiguration"), on the Python model: the PC localizes the fleet, hands it
the problem and beats the rounds; each module decides its moves (Figure 10), asks its
substrate and holders over the side IR links and rotates itself, and the world's physics
judges every move. No frame per move crosses the centre channel."""

from __future__ import annotations

import pytest

from bus.codec import Kind
from bus.lattice import Cell
from bus.messages import Pose, WorldEvent
from bus.scenario import loads
from planner_svc.bringup import BringUp
from planner_svc.rounds import RoundDriver, WalterProblem

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
#: groove beside it) and asks at once to go CCW under the anchor into (0, -1). In round 3 both
#: would turn about the anchor from two sides that meet at a joint, which would make the
#: anchor's two repelling sides a drive pair of its own: the anchor answers the first to ask
#: (m2, in the window of global direction 3; m3 asks in window 4), so m2 goes, m3 waits a
#: round (its log line says a request went unanswered) and goes over the anchor in round 4.
#: m2 and m3, side by side in round 3, each open their own pin on the other.
CHAIN3_PROBLEM = WalterProblem(3, 2, 0, Cell(0, 0), ((Cell(0, 1), True, 0), (Cell(0, -1), False, 0)))
CHAIN3_MOVES = [(1, "m3", "CW", (-2, 1)), (2, "m3", "CW", (-1, 1)), (3, "m2", "CCW", (0, -1)),
                (4, "m3", "CW", (0, 1))]


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


def _run(toml: str, problem: WalterProblem) -> Rig:
    rig = Rig(toml)
    rig.mark = len(rig.frames)
    rig.driver.upload(problem)
    rig.starts = []  # sim time of each round's end
    rig.result = rig.driver.run(8, progress=lambda r, heard: rig.starts.append(rig.clock.now_ns()))
    return rig


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
    # m3 arrives last, in round 4: its busy slot is silent
    assert chain3.result.done and chain3.result.rounds == 4
    assert all(chain3.result.busy[:3]) and chain3.result.busy[3] == 0


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
    assert [v["position"] for v in m3] == [0] * 4 and all(v["direction"] == "CW" for v in m3)
    assert [v["moved"] for v in m3] == [True, True, False, True] and m3[3]["stopped"]
    assert [v["unanswered"] for v in m3] == [False, False, True, False]
    # m2 waits in I while m3 rounds the end (which turns about it twice and is counted once),
    # is free in round 3 and goes CCW from position 1
    assert [v["free"] for v in m2] == [False, False, True, True]
    assert [v["moved"] for v in m2] == [False, False, True, False]
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

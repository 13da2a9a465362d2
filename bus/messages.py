"""Typed records for everything on the bus that is not a frame (JSON on the wire).

Every record has ``sim_time_ns``. ``to_json``/``from_json`` are shared by all of
them; the key each one travels on is in :mod:`bus.keys`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from typing import Any, ClassVar, TypeVar

T = TypeVar("T", bound="Record")
_FIELD_NAMES: dict[type, frozenset[str]] = {}  # Record.from_dict's field names per class


@dataclass
class Record:
    TOPIC: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        # asdict's deep copies cost more than the JSON they feed; fields holding a dataclass
        # (none today) still take asdict's way
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        if any(is_dataclass(v) for v in d.values()):
            d = asdict(self)
        d["type"] = self.TOPIC
        return d

    def to_json(self) -> bytes:
        return json.dumps(self.to_dict(), separators=(",", ":")).encode()

    @classmethod
    def from_dict(cls: type[T], d: dict[str, Any]) -> T:
        names = _FIELD_NAMES.get(cls)
        if names is None:  # fields() builds its tuple on every call: once per class
            names = _FIELD_NAMES[cls] = frozenset(f.name for f in fields(cls))
        return cls(**{k: v for k, v in d.items() if k in names})

    @classmethod
    def from_json(cls: type[T], data: bytes | str) -> T:
        return cls.from_dict(json.loads(data))


@dataclass
class Pose(Record):
    """``world/pose/<module>``: where a module is (ground truth, or belief for real ones)."""

    TOPIC: ClassVar[str] = "pose"
    module: str  # endpoint, "m3"
    id: int
    x: int
    y: int
    orientation: int  # Yref of the module's true pose: global side = body side + orientation
    sim_time_ns: int
    kind: str = "virtual"  # "virtual" or "real"
    fixed: bool = False


@dataclass
class Actuators(Record):
    """``world/actuators/<module>``: actuator and LED state from the boards' port bits."""

    TOPIC: ClassVar[str] = "actuators"
    module: str
    sim_time_ns: int
    joints_open: list[bool]  # J1..J6, True = solenoid energised (joint open)
    magnets: list[int]  # S1..S6: +1 positive, -1 negative, 0 off, 2 both relays (fault)
    led_pos: list[bool]  # LEDs on, sides 1..6
    led_neg: list[bool]
    led_joint: list[bool]
    ir_channel: int | None  # transceiver selected by the IR multiplexer (0 = centre)
    ports: dict[str, dict[str, int]] = field(default_factory=dict)  # {"ctrl": {"A": 0x04,..}, "comm": ..}
    #: who saw these bits: "virtual" (a virtual module), "twin" (the world's copy of a real
    #: module) or "serial" (a real board's actuator report, read on its debug UART)
    origin: str = "virtual"


@dataclass
class Switches(Record):
    """``world/switches/<module>``: the optical switches, neighbour present per body side."""

    TOPIC: ClassVar[str] = "switches"
    module: str
    present: list[bool]  # body sides 1..6
    sim_time_ns: int

    @staticmethod
    def present_of(d: object) -> list[bool]:
        """The six switches of a sample's decoded JSON; ValueError if it is not one."""
        p = d.get("present") if isinstance(d, dict) else None
        if not isinstance(p, list) or len(p) != 6 or not all(v in (True, False, 0, 1) for v in p):
            raise ValueError(f"switches: 'present' must be six booleans, not {p!r}"[:200])
        return [bool(v) for v in p]


#: Event kinds a serial bridge (hil.bridge) publishes on ``event/hil.<port>``, and the planner
#: (planner_svc.executor) waits on: one spelling for both floors.
SERIAL_FAULT = "serial-fault"
SERIAL_RECOVERED = "serial-recovered"
SERIAL_TX_LOST = "serial-tx-lost"


@dataclass
class WorldEvent(Record):
    """``world/event``: move started/completed/refused, faults, collisions. Errors are data."""

    TOPIC: ClassVar[str] = "world-event"
    kind: str  # "move-started" "move-completed" "move-refused" "fault" "collision" ...
    sim_time_ns: int
    module: str | None = None
    reason: str = ""
    data: dict[str, Any] = field(default_factory=dict)
    # For moves: data = {"from": [x, y], "to": [x, y], "pivot": [px, py] (Cartesian),
    #                    "direction": "CW"|"CCW", "joint": j, "substrate": "m2",
    #                    "duration_ns": n, "orientation_before": o, "orientation_after": o}


@dataclass
class Energy(Record):
    """``world/energy``: electrical energy from actuator on-times (spec §8)."""

    TOPIC: ClassVar[str] = "energy"
    sim_time_ns: int
    module: str | None
    move_j: float  # energy of the move just finished (0 if not a move)
    run_j: float  # total of the run so far
    by_actuator: dict[str, float] = field(default_factory=dict)  # "magnets", "solenoids", "logic"


@dataclass
class PlannerState(Record):
    """``planner/state``: the planner's view at a step (overlays in the replay)."""

    TOPIC: ClassVar[str] = "planner-state"
    sim_time_ns: int
    step: int
    planner: str
    occupied: list[list[int]]
    goal: list[list[int]]
    electrons: list[list[int]] = field(default_factory=list)
    voids: list[list[int]] = field(default_factory=list)
    mobile: list[list[int]] = field(default_factory=list)
    potential_voids: list[list[int]] = field(default_factory=list)
    pairs: list[list[list[int]]] = field(default_factory=list)  # [[electron], [void]]
    value_cells: list[list[int]] = field(default_factory=list)
    values: list[float] = field(default_factory=list)


@dataclass
class PlannerProgress(Record):
    """``planner/progress``: one line of progress per step or move."""

    TOPIC: ClassVar[str] = "planner-progress"
    sim_time_ns: int
    step: int
    moves: int
    goal_filled: int
    goal_total: int
    message: str = ""
    done: bool = False
    ok: bool = True
    planned: int = 0  # moves in the plan (0: not planned yet, or a script)


@dataclass
class RunMeta(Record):
    """``meta``: what a recording is a recording of."""

    TOPIC: ClassVar[str] = "meta"
    scenario: str
    profile: str
    seed: int
    planner: str
    clock: str
    argv: list[str]
    versions: dict[str, str]
    sim_time_ns: int = 0
    fleet: str = "default"

"""Scenario files (TOML): the fleet, the fixed module, the goal, obstacles, profile, seed.

Cells are ``[x, y]`` lists, or a thesis-style 0/1 matrix (list of row strings
such as ``"1 0 1"``; spec §2). Built-in scenarios live in ``bus/scenarios/``.
The keys, their types and ranges are declared in :data:`SCHEMA` (a JSON Schema); what a
schema cannot say (one cell per module, connected structures, the fixed module in the
goal) is checked by the named steps of ``_build``. A malformed file raises a one-line
:class:`ScenarioError` naming the file, the line of the key, and what was expected.
"""

from __future__ import annotations

import difflib
import functools
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Callable

import fastjsonschema

from .codec import COORD_LIMIT, coord_range
from .errors import HexbenchError
from .faults import ActuatorFault, FaultSpecError
from .lattice import Cell, matrix_to_cells, offset_in_frame

PROFILES = ("v2", "thesis-2009")
#: virtual: the Python model in the fleet; real: a board behind serial ports; firmware: the
#: C firmware in simavr behind ptys (hil.firmware), bridged like a real board.
KINDS = ("virtual", "real", "firmware")
#: What runs on a virtual module: the Python programs ("model"), the C firmware compiled
#: for the host ("firmware", module_sim.firmware) or the flashed images in simavr cores
#: in-process ("simavr", module_sim.simavr).
PROGRAMS = ("model", "firmware", "simavr")
#: Planners a scenario may ask for (``planner = "walter"``); planner_svc registers them
#: (tests/planner/test_walter.py holds the two lists equal).
PLANNERS = ("thesis-serial", "thesis-parallel", "exact", "complete", "walter")
#: The programs built for 300 baud IR (their localization slots are in ticks of it).
C_PROGRAMS = ("firmware", "simavr")
#: What a virtual module runs when neither its scenario nor its entry says (``program`` None):
#: the C firmware on the fleet core where the run allows it, else the Python programs, with the
#: reason in one line (module_sim.fleet.default_program).


class ScenarioError(HexbenchError, ValueError):
    """A scenario that cannot be used; the message says where and what was expected."""


@dataclass(frozen=True)
class ModuleSpec:
    id: int
    cell: Cell
    kind: str = "virtual"
    orientation: int = 0  # Yref: 60-degree steps from the global to the body frame
    port: str | None = None  # serial URL of a real module's central IR transceiver
    debug_port: str | None = None
    program: str | None = None  # None: the scenario's


@dataclass(frozen=True)
class Reach:
    """The cells the protocol can name: MSG1, POS and Select mode 2 carry a cell relative to the
    reference (the fixed module after ``Ref``), in its frame, within ``COORD_LIMIT`` of the
    profile (bus.codec). A run whose start, goal or plan leaves it is refused before it boots."""

    reference: Cell
    orientation: int
    profile: str

    def beyond(self, cell: Cell) -> str | None:
        """None if the protocol carries ``cell``, else one clause saying why not."""
        dx, dy = offset_in_frame(cell, self.reference, self.orientation)
        if max(abs(dx), abs(dy)) <= COORD_LIMIT[self.profile]:
            return None
        return (f"cell {list(cell)} is ({dx}, {dy}) from the fixed module {list(self.reference)} "
                f"in its frame; {self.profile} carries {coord_range(self.profile)} from it")


@dataclass
class Scenario:
    name: str
    modules: list[ModuleSpec]
    fixed: Cell
    goal: list[Cell]
    obstacles: list[Cell] = field(default_factory=list)
    profile: str = "v2"
    seed: int = 0
    description: str = ""
    source: str = "<built-in>"
    ir_baud: int = 300
    bit_error_rate: float = 0.0
    faults: list[ActuatorFault] = field(default_factory=list)  # injected by the world
    #: what virtual modules run unless a module says otherwise; None: the default (above C_PROGRAMS)
    program: str | None = None
    planner: str | None = None  # the planner the scenario is made for (None: the command's)

    def program_of(self, module: ModuleSpec) -> str | None:
        return module.program or self.program

    @property
    def initial(self) -> list[Cell]:
        return sorted((m.cell for m in self.modules), key=lambda c: (c.y, c.x))

    def module_at(self, cell: Cell) -> ModuleSpec | None:
        return next((m for m in self.modules if m.cell == cell), None)

    @property
    def fixed_module(self) -> ModuleSpec:
        m = self.module_at(self.fixed)
        assert m is not None  # checked when loading
        return m

    @property
    def reach(self) -> Reach:
        return Reach(self.fixed, self.fixed_module.orientation, self.profile)


def builtin_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("bus.scenarios").iterdir()
                  if p.name.endswith(".toml"))


def load(name_or_path: str | Path) -> Scenario:
    """A built-in scenario by name, or a TOML file by path."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise ScenarioError(f"{p}: no such scenario file")
        return loads(p.read_text(encoding="utf-8"), source=str(p))
    name = str(name_or_path)
    if name in builtin_names():
        text = resources.files("bus.scenarios").joinpath(name + ".toml").read_text(encoding="utf-8")
        return loads(text, source=f"<built-in {name}>")
    close = difflib.get_close_matches(name, builtin_names(), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise ScenarioError(f"{name!r} is neither a scenario file nor a built-in scenario{hint}; "
                        f"built-ins: {', '.join(builtin_names())}")


def loads(text: str, source: str = "<string>") -> Scenario:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column (\d+)\)", str(exc))
        if m:
            where = f"line {m.group(1)}, column {m.group(2)}"
        else:  # "(at end of document)": the problem is on the last line
            where = f"line {max(1, len(text.rstrip().splitlines()))} (end of file)"
        msg = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", str(exc))
        raise ScenarioError(f"{source}: {where}: invalid TOML: {msg}") from None
    return _build(data, source, text)


# --- the schema ----------------------------------------------------------------------
# Every key of a scenario file, its type and range, as a JSON Schema (draft 4: there an
# integer is never 1.0) checked by fastjsonschema. Each "description" is what an error
# says was expected at that key; a failure further down (an item of a cell) is reported
# at the nearest key above it that has one. What a schema cannot say (one cell per
# module, a connected fleet, the fixed module in the goal) the steps of _build check.
_CELL = {"description": "a cell [x, y] of two integers", "type": "array",
         "items": {"type": "integer"}, "minItems": 2, "maxItems": 2}
_CELLS = {"description": "a list of cells [[x, y], ...]", "type": "array", "items": _CELL}
_MATRIX = {"description": 'a thesis 0/1 matrix: a list of row strings like "1 0 1"',
           "type": "array", "items": {"type": "string"}, "minItems": 1}
_SERIAL_URL = {"description": "a serial URL string", "type": "string"}
_PROGRAM = {"description": "'model', 'firmware' or 'simavr'", "enum": list(PROGRAMS)}
_MODULE = {
    "description": "a table with cell, id, kind", "type": "object",
    "additionalProperties": False, "required": ["cell"],
    "properties": {
        "cell": _CELL,
        "id": {"description": "a hardware id 1..255 (the DIP switches)", "type": "integer",
               "minimum": 1, "maximum": 255},
        "kind": {"description": "'virtual', 'real' or 'firmware'", "enum": list(KINDS)},
        "orientation": {"description": "an integer 0..5 (60-degree steps)", "type": "integer",
                        "minimum": 0, "maximum": 5},
        "port": _SERIAL_URL,
        "debug_port": _SERIAL_URL,
        "program": _PROGRAM,
    },
}
SCHEMA: dict[str, Any] = {
    "$schema": "http://json-schema.org/draft-04/schema#",
    "type": "object", "additionalProperties": False,
    "properties": {
        "name": {"description": "a string", "type": "string"},
        "description": {"description": "a string", "type": "string"},
        "profile": {"description": " or ".join(repr(p) for p in PROFILES), "enum": list(PROFILES)},
        "seed": {"description": "an integer", "type": "integer"},
        "modules": {"description": "an array of tables [[modules]]", "type": "array",
                    "items": _MODULE},
        "initial": _CELLS,
        "initial_matrix": _MATRIX,
        "goal": _CELLS,
        "goal_matrix": _MATRIX,
        "fixed": _CELL,
        "obstacles": _CELLS,
        "program": _PROGRAM,
        "planner": {"description": "a planner: " + ", ".join(repr(p) for p in PLANNERS),
                    "enum": list(PLANNERS)},
        "ir_baud": {"description": "a positive baud rate", "type": "integer", "minimum": 1},
        "bit_error_rate": {"description": "a probability 0 <= p < 1", "type": "number",
                           "minimum": 0, "maximum": 1, "exclusiveMaximum": True},
        "faults": {"description": 'an array of fault strings such as "m3.S2-:off"',
                   "type": "array", "items": {"type": "string"}},
    },
}


@functools.cache
def _validator() -> Callable[[Any], Any]:
    return fastjsonschema.compile(SCHEMA)


def _build(d: dict[str, Any], source: str, text: str) -> Scenario:
    """The scenario of a parsed file, checked step by step: the first problem raises a
    one-line :class:`ScenarioError` naming the file, the line of the key, and what was
    expected there."""
    at = _Where(source, text)
    _check_schema(d, at)                            # every key known, of its type and range
    modules = _fleet(d, at)                         # distinct cells and ids, one structure
    goal = _goal(d, modules, at)                    # a distinct goal cell per module
    fixed = _fixed(d, modules, goal, at)            # a module's cell, also in the goal
    obstacles = _obstacles(d, modules, goal, at)    # clear of modules and goals
    faults = _faults(d, modules, at)                # each on a module of the fleet
    profile = d.get("profile", "v2")
    _reach(d, modules, goal, fixed, profile, at)    # cells the protocol can name
    program, ir_baud = d.get("program"), d.get("ir_baud", 300)
    _firmware_baud(program, ir_baud, modules, at)   # the C programs talk at 300 baud
    name = d.get("name", Path(source).stem if not source.startswith("<") else "scenario")
    return Scenario(name=name, modules=modules, fixed=fixed, goal=goal, obstacles=obstacles,
                    profile=profile, seed=d.get("seed", 0),
                    description=d.get("description", ""), source=source, ir_baud=ir_baud,
                    bit_error_rate=float(d.get("bit_error_rate", 0.0)), faults=faults,
                    program=program, planner=d.get("planner"))


# --- where a problem is: keys to lines ---------------------------------------------------
#: A path into the file, as ``("modules", 1, "kind")`` for ``modules[1].kind``.
Key = tuple[str | int, ...]

_ARRAY_TABLE = re.compile(r"\s*\[\[\s*([\w-]+)\s*\]\]")
_TABLE = re.compile(r"\s*\[\s*([\w.-]+)\s*\]")
_KEY_LINE = re.compile(r"""\s*("[^"]*"|'[^']*'|[\w-]+)\s*=""")
_MULTILINE_QUOTES = ('"' * 3, "'" * 3)


class _Where:
    """The file a scenario comes from: its name, and the line each key is on."""

    def __init__(self, source: str, text: str) -> None:
        self.source = source
        self.lines = _key_lines(text)

    def line(self, key: Key) -> str:
        """``"line N, "``: the line of ``key``, else of the nearest key above it (a
        table's header, an array's key); ``""`` if none is known."""
        for n in range(len(key), 0, -1):
            if key[:n] in self.lines:
                return f"line {self.lines[key[:n]]}, "
        return ""

    def error(self, message: str, key: Key = ()) -> ScenarioError:
        return ScenarioError(f"{self.source}: {self.line(key)}{message}")

    def expected(self, key: Key, expected: str, got: Any) -> ScenarioError:
        return self.error(f"key '{_dotted(key)}': expected {expected}, got {got!r}", key)


def _key_lines(text: str) -> dict[Key, int]:
    """The line of every top-level key, table header (the second ``[[modules]]`` is
    ``("modules", 1)``) and key of a table, read from the text (tomllib keeps no
    positions); lines inside multi-line strings hold no keys."""
    lines: dict[Key, int] = {}
    table: Key = ()
    count: dict[str, int] = {}
    in_string = False
    for n, line in enumerate(text.splitlines(), 1):
        if not in_string:
            if m := _ARRAY_TABLE.match(line):
                name = m.group(1)
                table = (name, count.get(name, 0))
                count[name] = count.get(name, 0) + 1
                lines.setdefault(table, n)
            elif m := _TABLE.match(line):
                table = tuple(m.group(1).split("."))
                lines.setdefault(table, n)
            elif m := _KEY_LINE.match(line):
                lines.setdefault((*table, m.group(1).strip("'\"")), n)
        if sum(line.count(q) for q in _MULTILINE_QUOTES) % 2:
            in_string = not in_string
    return lines


def _dotted(key: Key) -> str:
    """``("modules", 1, "kind")`` as a reader writes it: ``modules[1].kind``."""
    out = ""
    for part in key:
        out += f"[{part}]" if isinstance(part, int) else f".{part}" if out else part
    return out


def _at(d: Any, key: Key) -> Any:
    return functools.reduce(lambda v, part: v[part], key, d)


# --- the steps of _build -----------------------------------------------------------------
def _check_schema(d: dict[str, Any], at: _Where) -> None:
    """Every key known, of its type and range (:data:`SCHEMA`)."""
    try:
        _validator()(d)
    except fastjsonschema.JsonSchemaValueException as exc:
        raise _schema_error(exc, d, at) from None


def _schema_error(exc: fastjsonschema.JsonSchemaValueException, d: dict[str, Any],
                  at: _Where) -> ScenarioError:
    """A schema failure in a user's words: the key and its line, what was expected
    there, what is there (an unknown key: the keys expected, the closest first)."""
    path: Key = tuple(int(p) if p.isdigit() else p for p in exc.path[1:])
    nodes = [SCHEMA]        # the schema at each step of the path
    for part in path:
        nodes.append(nodes[-1]["items"] if isinstance(part, int)
                     else nodes[-1]["properties"][part])
    node, value = nodes[-1], _at(d, path)
    if exc.rule == "additionalProperties":
        allowed = sorted(node["properties"])
        k = sorted(set(value) - set(allowed))[0]
        close = difflib.get_close_matches(k, allowed, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        return at.error(f"unknown key '{_dotted((*path, k))}'{hint}; expected one of: "
                        f"{', '.join(allowed)}", (*path, k))
    if exc.rule == "required":
        k = next(k for k in node["required"] if k not in value)
        return at.error(f"key '{_dotted((*path, k))}' is missing: expected "
                        f"{node['properties'][k]['description']}", path)
    depth = max(n for n, node in enumerate(nodes) if "description" in node)
    value = _at(d, path[:depth])
    expected = nodes[depth]["description"]
    if exc.rule == "enum" and isinstance(value, str):
        close = difflib.get_close_matches(value, [str(v) for v in nodes[depth]["enum"]], n=1)
        if close:
            expected += f" (did you mean {close[0]!r}?)"
    return at.expected(path[:depth], expected, value)


def _cell(v: list[int], key: Key, at: _Where) -> Cell:
    return Cell(v[0], v[1])


def _cells(v: list[list[int]], key: str, at: _Where) -> list[Cell]:
    return [_cell(c, (key, i), at) for i, c in enumerate(v)]


def _matrix(v: list[str], key: str, at: _Where) -> list[Cell]:
    try:
        return matrix_to_cells(v)
    except ValueError as exc:
        raise at.expected((key,), f"a thesis 0/1 matrix ({exc})", v) from None


def _fleet(d: dict[str, Any], at: _Where) -> list[ModuleSpec]:
    """The modules, from ``[[modules]]``, or from ``initial`` or ``initial_matrix`` (ids
    1, 2, ...): at least one, no two on one cell or with one id, one connected structure."""
    modules: list[ModuleSpec] = []
    placed: list[Key] = []      # per module, the key that places it
    for i, m in enumerate(d.get("modules", [])):
        modules.append(ModuleSpec(m.get("id", i + 1), _cell(m["cell"], ("modules", i, "cell"), at),
                                  m.get("kind", "virtual"), m.get("orientation", 0),
                                  m.get("port"), m.get("debug_port"), m.get("program")))
        placed.append(("modules", i, "cell"))
    for key, parse in (("initial", _cells), ("initial_matrix", _matrix)):
        if key in d:
            if modules:
                raise at.error(f"key '{key}': give the fleet either as [[modules]] or as "
                               "initial cells, not both", (key,))
            cells = parse(d[key], key, at)
            modules.extend(ModuleSpec(k + 1, c) for k, c in enumerate(cells))
            placed.extend((key, k) if key == "initial" else (key,) for k in range(len(cells)))
    if not modules:
        raise at.error("no modules: give [[modules]], 'initial' or 'initial_matrix'")
    seen_cells: dict[Cell, int] = {}
    seen_ids: set[int] = set()
    for m, key in zip(modules, placed):
        if m.cell in seen_cells:
            raise at.error(f"modules {seen_cells[m.cell]} and {m.id} share cell {m.cell}", key)
        if m.id in seen_ids:
            raise at.error(f"hardware id {m.id} is used twice", key[:2] + ("id",))
        seen_cells[m.cell] = m.id
        seen_ids.add(m.id)
    apart = _connected([m.cell for m in modules])
    if apart:
        raise at.error("the fleet is not one connected structure: "
                       f"{', '.join(str(list(c)) for c in apart[:6])}"
                       f"{' ...' if len(apart) > 6 else ''} touch no module of the rest "
                       "(it could not be localized from the fixed module, nor move)")
    return modules


def _goal(d: dict[str, Any], modules: list[ModuleSpec], at: _Where) -> list[Cell]:
    """``goal`` or ``goal_matrix`` (by default, where the modules are): one distinct cell
    per module, one connected structure."""
    if "goal" in d and "goal_matrix" in d:
        raise at.error("give either 'goal' or 'goal_matrix', not both", ("goal_matrix",))
    if "goal" in d:
        goal = _cells(d["goal"], "goal", at)
    elif "goal_matrix" in d:
        goal = _matrix(d["goal_matrix"], "goal_matrix", at)
    else:
        goal = [m.cell for m in modules]
    if len(set(goal)) != len(goal):
        raise at.expected(("goal",), "distinct cells", [list(c) for c in goal])
    if len(goal) != len(modules):
        raise at.error(f"key 'goal': {len(goal)} goal cells for {len(modules)} modules; "
                       "every module needs a goal cell", ("goal",))
    apart = _connected(goal)
    if apart:
        raise at.error("the goal is not one connected structure: "
                       f"{', '.join(str(list(c)) for c in apart[:6])} touch none of the rest",
                       ("goal",))
    return goal


def _fixed(d: dict[str, Any], modules: list[ModuleSpec], goal: list[Cell], at: _Where) -> Cell:
    """``fixed``, or by the thesis convention the cell common to the fleet and the goal
    with the lowest y, then the lowest x: a module's cell that is also in the goal."""
    cells = {m.cell for m in modules}
    if "fixed" in d:
        fixed = _cell(d["fixed"], ("fixed",), at)
    else:
        common = sorted(set(goal) & cells, key=lambda c: (c.y, c.x))
        if not common:
            raise at.error("key 'fixed' is missing and no cell is in both the fleet and the "
                           "goal to choose it from")
        fixed = common[0]
    if fixed not in cells:
        raise at.expected(("fixed",), "the cell of one of the modules", list(fixed))
    if fixed not in goal:
        raise at.expected(("fixed",), "a cell that is also in the goal (the fixed module "
                          "never moves)", list(fixed))
    return fixed


def _reach(d: dict[str, Any], modules: list[ModuleSpec], goal: list[Cell], fixed: Cell,
           profile: str, at: _Where) -> None:
    """Every module's cell and every goal cell within what the protocol carries from the fixed
    module (:class:`Reach`), checked where MSG1 and POS carry them: relative to it."""
    ref = next(m for m in modules if m.cell == fixed)
    reach = Reach(fixed, ref.orientation, profile)
    fleet_key = next(k for k in ("modules", "initial", "initial_matrix") if k in d)
    goal_key = next((k for k in ("goal", "goal_matrix") if k in d), fleet_key)
    for what, key, cells in (("the fleet", fleet_key, [m.cell for m in modules]),
                             ("the goal", goal_key, goal)):
        for i, cell in enumerate(cells):
            if why := reach.beyond(cell):
                where: Key = {"modules": (key, i, "cell"), "initial": (key, i), "goal": (key, i)}.get(key, (key,))
                raise at.error(f"{what} leaves what the protocol can name: {why}", where)


def _obstacles(d: dict[str, Any], modules: list[ModuleSpec], goal: list[Cell],
               at: _Where) -> list[Cell]:
    obstacles = _cells(d.get("obstacles", []), "obstacles", at)
    clash = (set(obstacles) & {m.cell for m in modules}) | (set(obstacles) & set(goal))
    if clash:
        raise at.expected(("obstacles",), "cells free of modules and goals",
                          [list(c) for c in clash])
    return obstacles


def _faults(d: dict[str, Any], modules: list[ModuleSpec], at: _Where) -> list[ActuatorFault]:
    ids = {m.id for m in modules}
    faults = []
    for i, spec in enumerate(d.get("faults", [])):
        try:
            f = ActuatorFault.parse(spec)
        except FaultSpecError as exc:
            raise at.error(f"key 'faults[{i}]': {exc}", ("faults", i)) from None
        if int(f.module[1:]) not in ids:
            raise at.expected(("faults", i), "a fault on a module of this scenario", spec)
        faults.append(f)
    return faults


def _firmware_baud(program: str | None, ir_baud: int, modules: list[ModuleSpec], at: _Where) -> None:
    if ir_baud != 300 and (program in C_PROGRAMS or any(m.program in C_PROGRAMS for m in modules)):
        raise at.expected(("ir_baud",), "300 with program 'firmware' or 'simavr' (the C programs "
                          "are built for 300 baud IR)", ir_baud)


def _connected(cells: list[Cell]) -> list[Cell] | None:
    """None if ``cells`` are one connected structure, else the cells cut off from the first."""
    todo, seen, have = [cells[0]], {cells[0]}, set(cells)
    while todo:
        c = todo.pop()
        for s in range(1, 7):
            n = c.neighbour(s)
            if n in have and n not in seen:
                seen.add(n)
                todo.append(n)
    return None if len(seen) == len(have) else sorted(have - seen, key=lambda c: (c.y, c.x))


def parse_real(spec: str) -> tuple[int, str, str | None]:
    """``ID=PORT`` or ``ID=PORT,DEBUG_PORT`` (``--real``): module ``ID`` is a real board
    whose central IR transceiver is on ``PORT`` and whose debug UART1 is on ``DEBUG_PORT``."""
    ident, sep, ports = spec.partition("=")
    port, _, debug = ports.partition(",")
    if not sep or not ident.strip().lstrip("m").isdigit() or not port:
        raise ScenarioError(f"--real {spec!r}: expected ID=PORT or ID=PORT,DEBUG_PORT, "
                            "e.g. 1=/dev/ttyUSB0,/dev/ttyUSB1")
    return int(ident.strip().lstrip("m")), port, debug or None


def override(sc: Scenario, *, seed: int | None = None, profile: str | None = None,
             faults: list[str] = (), real: list[str] = (), firmware: list[str] = (),
             program: str | None = None) -> Scenario:
    """A copy of ``sc`` with command-line overrides; extra fault specs are checked against
    the fleet, and ``real`` specs (:func:`parse_real`) make modules real boards on ports
    (:class:`ScenarioError` names the bad one); ``firmware`` ids (``3`` or ``m3``) make
    modules run the C firmware in simavr; ``program`` sets what every virtual module runs."""
    import dataclasses

    ids = {f"m{m.id}" for m in sc.modules}
    boards = {}
    for spec in real:
        ident, port, debug = parse_real(spec)
        if f"m{ident}" not in ids:
            raise ScenarioError(f"--real {spec}: scenario {sc.name!r} has no module m{ident}")
        boards[ident] = (port, debug)
    fw = set()
    for spec in firmware:
        text = str(spec).strip().lstrip("m")
        if not text.isdigit() or f"m{int(text)}" not in ids:
            raise ScenarioError(f"--firmware {spec}: scenario {sc.name!r} has no module m{text}")
        if int(text) in boards:
            raise ScenarioError(f"--firmware {spec}: m{text} is already a real board (--real)")
        fw.add(int(text))
    modules = [dataclasses.replace(m, kind="real", port=boards[m.id][0], debug_port=boards[m.id][1])
               if m.id in boards else dataclasses.replace(m, kind="firmware") if m.id in fw else m
               for m in sc.modules]
    extra = []
    for spec in faults:
        try:
            f = ActuatorFault.parse(spec)
        except FaultSpecError as exc:
            raise ScenarioError(str(exc)) from None
        if f.module not in ids:
            raise ScenarioError(f"fault {spec}: scenario {sc.name!r} has no module {f.module}")
        extra.append(f)
    if profile is not None and profile not in PROFILES:
        raise ScenarioError(f"profile {profile!r}: expected one of {', '.join(PROFILES)}")
    if profile is not None:
        reach = dataclasses.replace(sc.reach, profile=profile)
        for what, cells in (("fleet", sc.initial), ("goal", sc.goal)):
            why = next((w for c in cells if (w := reach.beyond(c))), None)
            if why:
                raise ScenarioError(f"--profile {profile}: the {what} of scenario {sc.name!r} leaves "
                                    f"what the protocol can name: {why}")
    if program is not None and program not in PROGRAMS:
        raise ScenarioError(f"program {program!r}: expected one of {', '.join(PROGRAMS)}")
    if program is not None:
        modules = [dataclasses.replace(m, program=None) for m in modules]
    if program in C_PROGRAMS and sc.ir_baud != 300:
        raise ScenarioError(f"--program {program}: scenario {sc.name!r} has ir_baud {sc.ir_baud}; "
                            "the C programs are built for 300 baud IR")
    return dataclasses.replace(sc, modules=modules, faults=list(sc.faults) + extra,
                               program=program or sc.program,
                               seed=sc.seed if seed is None else seed,
                               profile=profile or sc.profile)

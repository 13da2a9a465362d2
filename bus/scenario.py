"""Scenario files (TOML): the fleet, the fixed module, the goal, obstacles, profile, seed.

Cells are ``[x, y]`` lists, or a thesis-style 0/1 matrix (list of row strings
such as ``"1 0 1"``; spec §2). Built-in scenarios live in ``bus/scenarios/``.
A malformed file raises :class:`ScenarioError` naming the file, the line or key,
and what was expected.
"""

from __future__ import annotations

import difflib
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from .errors import HexbenchError
from .faults import ActuatorFault, FaultSpecError
from .lattice import Cell, matrix_to_cells

PROFILES = ("v2", "thesis-2009")
#: virtual: the Python model in the fleet; real: a board behind serial ports; firmware: the
#: C firmware in simavr behind ptys (hil.firmware), bridged like a real board.
KINDS = ("virtual", "real", "firmware")
_TOP_KEYS = {"name", "description", "profile", "seed", "fixed", "goal", "goal_matrix", "initial",
             "initial_matrix", "obstacles", "modules", "ir_baud", "bit_error_rate", "faults",
             "program"}
_MODULE_KEYS = {"cell", "id", "kind", "orientation", "port", "debug_port", "program"}
#: What runs on a virtual module: the Python programs ("model") or the C firmware compiled
#: for the host ("firmware", module_sim.firmware).
PROGRAMS = ("model", "firmware")


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
    program: str = "model"  # what virtual modules run unless a module says otherwise

    def program_of(self, module: ModuleSpec) -> str:
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


def _line_of(text: str, key: str) -> str:
    for n, line in enumerate(text.splitlines(), 1):
        if re.match(rf"\s*{re.escape(key)}\s*=", line):
            return f"line {n}, "
    return ""


def _err(source: str, text: str, key: str, expected: str, got: Any) -> ScenarioError:
    leaf = key.rsplit(".", 1)[-1].split("[")[0]
    return ScenarioError(f"{source}: {_line_of(text, leaf)}key '{key}': expected {expected}, got {got!r}")


#: Coordinates a module can be told and report: MSG1 carries two decimal digits and a sign.
COORD_LIMIT = 99


def _cell(v: Any, key: str, source: str, text: str) -> Cell:
    if (isinstance(v, list) and len(v) == 2 and all(isinstance(c, int) and not isinstance(c, bool)
                                                    for c in v)):
        if max(abs(v[0]), abs(v[1])) > COORD_LIMIT:
            raise _err(source, text, key, f"coordinates within -{COORD_LIMIT}..{COORD_LIMIT} "
                       "(what MSG1 can carry)", v)
        return Cell(v[0], v[1])
    raise _err(source, text, key, "a cell [x, y] of two integers", v)


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


def _cells(v: Any, key: str, source: str, text: str) -> list[Cell]:
    if not isinstance(v, list):
        raise _err(source, text, key, "a list of cells [[x, y], ...]", v)
    return [_cell(c, f"{key}[{i}]", source, text) for i, c in enumerate(v)]


def _matrix(v: Any, key: str, source: str, text: str) -> list[Cell]:
    if not isinstance(v, list) or not v:
        raise _err(source, text, key, "a thesis 0/1 matrix: a list of row strings like \"1 0 1\"", v)
    try:
        return matrix_to_cells(v)
    except (ValueError, TypeError) as exc:
        raise _err(source, text, key, f"a thesis 0/1 matrix ({exc})", v) from None


def _unknown(keys: set[str], allowed: set[str], where: str, source: str, text: str) -> None:
    for k in sorted(keys - allowed):
        close = difflib.get_close_matches(k, sorted(allowed), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise ScenarioError(f"{source}: {_line_of(text, k)}unknown key '{where}{k}'{hint}; "
                            f"expected one of: {', '.join(sorted(allowed))}")


def _build(d: dict[str, Any], source: str, text: str) -> Scenario:
    _unknown(set(d), _TOP_KEYS, "", source, text)
    name = d.get("name", Path(source).stem if not source.startswith("<") else "scenario")
    if not isinstance(name, str):
        raise _err(source, text, "name", "a string", name)
    profile = d.get("profile", "v2")
    if profile not in PROFILES:
        raise _err(source, text, "profile", " or ".join(repr(p) for p in PROFILES), profile)
    seed = d.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool):
        raise _err(source, text, "seed", "an integer", seed)

    modules: list[ModuleSpec] = []
    if "modules" in d:
        if not isinstance(d["modules"], list):
            raise _err(source, text, "modules", "an array of tables [[modules]]", d["modules"])
        for i, m in enumerate(d["modules"]):
            key = f"modules[{i}]"
            if not isinstance(m, dict):
                raise _err(source, text, key, "a table with cell, id, kind", m)
            _unknown(set(m), _MODULE_KEYS, key + ".", source, text)
            if "cell" not in m:
                raise ScenarioError(f"{source}: key '{key}.cell' is missing: every module needs a cell")
            cell = _cell(m["cell"], f"{key}.cell", source, text)
            ident = m.get("id", i + 1)
            if not isinstance(ident, int) or isinstance(ident, bool) or not 1 <= ident <= 255:
                raise _err(source, text, f"{key}.id", "a hardware id 1..255 (the DIP switches)", ident)
            kind = m.get("kind", "virtual")
            if kind not in KINDS:
                raise _err(source, text, f"{key}.kind", "'virtual', 'real' or 'firmware'", kind)
            orient = m.get("orientation", 0)
            if not isinstance(orient, int) or isinstance(orient, bool) or not 0 <= orient <= 5:
                raise _err(source, text, f"{key}.orientation", "an integer 0..5 (60-degree steps)", orient)
            for pk in ("port", "debug_port"):
                if pk in m and not isinstance(m[pk], str):
                    raise _err(source, text, f"{key}.{pk}", "a serial URL string", m[pk])
            prog = m.get("program")
            if prog is not None and prog not in PROGRAMS:
                raise _err(source, text, f"{key}.program", "'model' or 'firmware'", prog)
            modules.append(ModuleSpec(ident, cell, kind, orient, m.get("port"), m.get("debug_port"),
                                      prog))
    for key, parse in (("initial", _cells), ("initial_matrix", _matrix)):
        if key in d:
            if modules:
                raise ScenarioError(f"{source}: {_line_of(text, key)}key '{key}': give the fleet "
                                    "either as [[modules]] or as initial cells, not both")
            start = len(modules) + 1
            modules.extend(ModuleSpec(start + k, c) for k, c in enumerate(parse(d[key], key, source, text)))
    if not modules:
        raise ScenarioError(f"{source}: no modules: give [[modules]], 'initial' or 'initial_matrix'")
    seen_cells: dict[Cell, int] = {}
    seen_ids: set[int] = set()
    for m in modules:
        if m.cell in seen_cells:
            raise ScenarioError(f"{source}: modules {seen_cells[m.cell]} and {m.id} share cell {m.cell}")
        if m.id in seen_ids:
            raise ScenarioError(f"{source}: hardware id {m.id} is used twice")
        seen_cells[m.cell] = m.id
        seen_ids.add(m.id)

    apart = _connected([m.cell for m in modules])
    if apart:
        raise ScenarioError(f"{source}: the fleet is not one connected structure: "
                            f"{', '.join(str(list(c)) for c in apart[:6])}"
                            f"{' ...' if len(apart) > 6 else ''} touch no module of the rest "
                            "(it could not be localized from the fixed module, nor move)")

    if "goal" in d and "goal_matrix" in d:
        raise ScenarioError(f"{source}: give either 'goal' or 'goal_matrix', not both")
    if "goal" in d:
        goal = _cells(d["goal"], "goal", source, text)
    elif "goal_matrix" in d:
        goal = _matrix(d["goal_matrix"], "goal_matrix", source, text)
    else:
        goal = [m.cell for m in modules]
    if len(set(goal)) != len(goal):
        raise _err(source, text, "goal", "distinct cells", [list(c) for c in goal])
    if len(goal) != len(modules):
        raise ScenarioError(f"{source}: {_line_of(text, 'goal')}key 'goal': {len(goal)} goal cells "
                            f"for {len(modules)} modules; every module needs a goal cell")

    if "fixed" in d:
        fixed = _cell(d["fixed"], "fixed", source, text)
    else:
        # The thesis convention: the cell common to I and G with the lowest y, then lowest x.
        common = sorted(set(goal) & set(seen_cells), key=lambda c: (c.y, c.x))
        if not common:
            raise ScenarioError(f"{source}: key 'fixed' is missing and no cell is in both the "
                                "fleet and the goal to choose it from")
        fixed = common[0]
    apart = _connected(goal)
    if apart:
        raise ScenarioError(f"{source}: {_line_of(text, 'goal')}the goal is not one connected "
                            f"structure: {', '.join(str(list(c)) for c in apart[:6])} touch none of "
                            "the rest")
    if fixed not in seen_cells:
        raise _err(source, text, "fixed", "the cell of one of the modules", list(fixed))
    if fixed not in goal:
        raise _err(source, text, "fixed", "a cell that is also in the goal (the fixed module never moves)",
                   list(fixed))
    obstacles = _cells(d.get("obstacles", []), "obstacles", source, text)
    clash = (set(obstacles) & set(seen_cells)) | (set(obstacles) & set(goal))
    if clash:
        raise _err(source, text, "obstacles", "cells free of modules and goals", [list(c) for c in clash])
    program = d.get("program", "model")
    if program not in PROGRAMS:
        raise _err(source, text, "program", "'model' or 'firmware'", program)
    ir_baud = d.get("ir_baud", 300)
    if not isinstance(ir_baud, int) or ir_baud <= 0:
        raise _err(source, text, "ir_baud", "a positive baud rate", ir_baud)
    ber = d.get("bit_error_rate", 0.0)
    if not isinstance(ber, (int, float)) or not 0 <= ber < 1:
        raise _err(source, text, "bit_error_rate", "a probability 0 <= p < 1", ber)
    faults = []
    raw_faults = d.get("faults", [])
    if not isinstance(raw_faults, list):
        raise _err(source, text, "faults", "an array of fault strings such as \"m3.S2-:off\"", raw_faults)
    for i, spec in enumerate(raw_faults):
        try:
            f = ActuatorFault.parse(str(spec))
        except FaultSpecError as exc:
            raise ScenarioError(f"{source}: {_line_of(text, 'faults')}key 'faults[{i}]': {exc}") from None
        if int(f.module[1:]) not in seen_ids:
            raise _err(source, text, f"faults[{i}]", "a fault on a module of this scenario", spec)
        faults.append(f)
    if ir_baud != 300 and (program == "firmware" or any(m.program == "firmware" for m in modules)):
        raise _err(source, text, "ir_baud", "300 with program 'firmware' (the C programs are built "
                   "for 300 baud IR)", ir_baud)
    return Scenario(name=name, modules=modules, fixed=fixed, goal=goal, obstacles=obstacles,
                    profile=profile, seed=seed, description=str(d.get("description", "")),
                    source=source, ir_baud=ir_baud, bit_error_rate=float(ber), faults=faults,
                    program=program)


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
    if program is not None and program not in PROGRAMS:
        raise ScenarioError(f"program {program!r}: expected one of {', '.join(PROGRAMS)}")
    if program is not None:
        modules = [dataclasses.replace(m, program=None) for m in modules]
    if program == "firmware" and sc.ir_baud != 300:
        raise ScenarioError(f"--program firmware: scenario {sc.name!r} has ir_baud {sc.ir_baud}; "
                            "the C programs are built for 300 baud IR")
    return dataclasses.replace(sc, modules=modules, faults=list(sc.faults) + extra,
                               program=program or sc.program,
                               seed=sc.seed if seed is None else seed,
                               profile=profile or sc.profile)

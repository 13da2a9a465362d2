"""Scenario files: built-ins load; bad files say where and what was expected."""

import pytest

from bus.lattice import Cell
from bus.scenario import ScenarioError, builtin_names, load, loads, override

BUILTINS = ["thesis-6", "thesis-6-reverse", "thesis-12", "thesis-sim", "pair", "localization"]


def test_every_builtin_loads():
    assert set(BUILTINS) <= set(builtin_names())
    for name in builtin_names():
        s = load(name)
        assert s.modules and len(s.goal) == len(s.modules)
        assert s.fixed in s.initial and s.fixed in s.goal


def test_thesis_fixed_module_rule():
    # the cell common to I and G with the lowest y, then lowest x
    assert load("thesis-6").fixed == Cell(1, 0)
    assert load("thesis-12").fixed == Cell(0, 2)
    assert load("localization").fixed == Cell(0, 0)


def test_issue_example_keys(tmp_path):
    p = tmp_path / "one-real.toml"
    p.write_text('name = "one-real"\nprofile = "thesis-2009"\nfixed = [0, 0]\n'
                 'goal = [[0, 0], [1, 0]]\n[[modules]]\ncell = [0, 0]\nid = 1\nkind = "real"\n'
                 '[[modules]]\ncell = [1, 0]\nid = 2\n')
    s = load(p)
    assert s.profile == "thesis-2009" and s.modules[0].kind == "real" and s.modules[1].kind == "virtual"


def test_matrix_and_list_forms_agree():
    a = loads('initial_matrix = ["1 1", "1 0"]\ngoal = [[0, 0], [0, 1], [1, 1]]')
    assert set(a.initial) == {Cell(0, 0), Cell(0, 1), Cell(1, 1)}


@pytest.mark.parametrize("text,needle", [
    ('name = "x"\ngoal = [[0, 0]\n', "line 2"),
    ('profile = "v3"\ninitial = [[0, 0]]', "key 'profile': expected 'v2' or 'thesis-2009', got 'v3'"),
    ('initial = [[0, 0]]\ngaol = [[0, 0]]', "unknown key 'gaol' (did you mean 'goal'?)"),
    ('[[modules]]\ncell = [0, "a"]', "key 'modules[0].cell': expected a cell [x, y]"),
    ('[[modules]]\ncell = [0, 0]\nkind = "robot"', "key 'modules[0].kind': expected 'virtual', 'real' or 'firmware'"),
    ('[[modules]]\ncell = [0, 0]\nid = 300', "hardware id 1..255"),
    ('initial = [[0, 0], [1, 0]]\ngoal = [[0, 0]]', "1 goal cells for 2 modules"),
    ('initial = [[0, 0], [0, 0]]', "share cell (0,0)"),
    ('initial_matrix = ["1 2"]', "key 'initial_matrix': expected a thesis 0/1 matrix"),
    ('initial = [[0, 0]]\nfixed = [5, 5]', "key 'fixed': expected the cell of one of the modules"),
    ('name = "x"', "no modules"),
    ('initial = [[0, 0], [99999999999, 0]]', "the fleet is not one connected structure"),
    ('initial = [[0, 0], [1, 0], [5, 5]]', "the fleet is not one connected structure: [5, 5]"),
    ('initial = [[0, 0], [1, 0]]\ngoal = [[0, 0], [3, 0]]', "the goal is not one connected structure"),
])
def test_bad_scenarios_name_the_problem(text, needle):
    with pytest.raises(ScenarioError) as exc:
        loads(text, source="bad.toml")
    assert "bad.toml" in str(exc.value) and needle in str(exc.value)


def test_error_names_the_line(tmp_path):
    p = tmp_path / "typo.toml"
    p.write_text('name = "t"\ninitial = [[0, 0]]\n\nprofil = "v2"\n')
    with pytest.raises(ScenarioError, match=r"typo.toml: line 4, unknown key 'profil'"):
        load(p)


@pytest.mark.parametrize("text, message", [
    # a key of the second [[modules]] table: its own line, not the first 'kind ='
    ('name = "two"\n[[modules]]\ncell = [0, 0]\nkind = "real"\n\n[[modules]]\ncell = [1, 0]\n'
     'kind = "robot"\n', "line 8, key 'modules[1].kind': expected 'virtual', 'real' or "
     "'firmware', got 'robot'"),
    ('[[modules]]\ncell = [0, 0]\n[[modules]]\nid = 4\n',
     "line 3, key 'modules[1].cell' is missing: expected a cell [x, y] of two integers"),
    ('[[modules]]\ncell = [0, 0]\nid = 2\n[[modules]]\ncell = [1, 0]\nid = 2\n',
     "line 6, hardware id 2 is used twice"),
    ('[[modules]]\ncell = [0, 0]\n[[modules]]\ncell = [0, 0]\n',
     "line 4, modules 1 and 2 share cell (0,0)"),
    # a multi-line string holds no keys
    ('description = """\ngoal = 3\n"""\ninitial = [[0, 0], [1, 0]]\n'
     'goal = [[0, 0], [1, 0], [2, 0]]', "line 5, key 'goal': 3 goal cells for 2 modules; every "
     "module needs a goal cell"),
    ('seed = 1.0\ninitial = [[0, 0]]', "line 1, key 'seed': expected an integer, got 1.0"),
    ('initial = [[0, 0]]\n[[modules]]\ncell = [1, 0]\nspeed = 3\n',
     "line 4, unknown key 'modules[0].speed'; expected one of: cell, debug_port, id, kind, "
     "orientation, port, program"),
])
def test_errors_name_the_line_of_the_key(text, message):
    with pytest.raises(ScenarioError) as exc:
        loads(text, source="bad.toml")
    assert str(exc.value) == f"bad.toml: {message}"


def test_unknown_builtin_suggests():
    with pytest.raises(ScenarioError, match="did you mean 'thesis-6'"):
        load("thesis-7")


def test_real_overrides_make_boards_on_ports():
    sc = override(load("thesis-6"), real=["2=/dev/ttyUSB0,/dev/ttyUSB1", "m5=socket://lab:7000"])
    by_id = {m.id: m for m in sc.modules}
    assert (by_id[2].kind, by_id[2].port, by_id[2].debug_port) == ("real", "/dev/ttyUSB0", "/dev/ttyUSB1")
    assert (by_id[5].kind, by_id[5].port, by_id[5].debug_port) == ("real", "socket://lab:7000", None)
    assert {m.kind for m in sc.modules if m.id not in (2, 5)} == {"virtual"}


@pytest.mark.parametrize("spec, needle", [
    ("2", "expected ID=PORT"), ("x=/dev/tty0", "expected ID=PORT"), ("2=", "expected ID=PORT"),
    ("9=/dev/tty0", "has no module m9"),
])
def test_bad_real_overrides_say_what_is_wrong(spec, needle):
    with pytest.raises(ScenarioError, match=needle):
        override(load("thesis-6"), real=[spec])


def test_firmware_modules_in_a_scenario_and_on_the_command_line(tmp_path):
    p = tmp_path / "fw.toml"
    p.write_text('name = "fw"\nfixed = [0, 0]\ngoal = [[0, 0], [0, 1]]\n[[modules]]\ncell = [0, 0]\n'
                 'kind = "firmware"\n[[modules]]\ncell = [1, 0]\n')
    assert [m.kind for m in load(p).modules] == ["firmware", "virtual"]
    sc = override(load("pair"), firmware=["m2"])
    assert [m.kind for m in sc.modules] == ["virtual", "firmware"]
    with pytest.raises(ScenarioError, match="has no module m7"):
        override(load("pair"), firmware=["7"])
    with pytest.raises(ScenarioError, match="already a real board"):
        override(load("pair"), real=["2=/dev/ttyUSB0"], firmware=["2"])
    p.write_text(p.read_text().replace('"firmware"', '"simavr"'))
    with pytest.raises(ScenarioError, match="'virtual', 'real' or 'firmware'"):
        load(p)


def test_the_firmware_program_needs_300_baud(tmp_path):
    p = tmp_path / "fast.toml"
    p.write_text('name = "fast"\nir_baud = 62500\nprogram = "firmware"\ninitial = [[0, 0], [1, 0]]\n')
    with pytest.raises(ScenarioError, match="ir_baud.*300 with program 'firmware'"):
        load(p)
    p.write_text('name = "fast"\nir_baud = 62500\ninitial = [[0, 0], [1, 0]]\n')
    with pytest.raises(ScenarioError, match="built for 300 baud IR"):
        override(load(p), program="firmware")
    assert override(load(p), program="model").program == "model"

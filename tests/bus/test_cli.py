"""The hexbench CLI over the contract (acceptance commands of the foundation issue)."""

import argparse
import re
import subprocess
import sys

import pytest

from hexbench.cli import build_parser, main


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hexbench", *args], capture_output=True, text=True,
                          timeout=60)


def _subcommands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """Every subcommand path of ``parser`` (``("firmware", "build")``), nested ones too."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name)
                yield from _subcommands(sub, (*path, name))


#: Read from the parser itself, so a new subcommand is covered without touching this file.
SUBCOMMANDS = list(_subcommands(build_parser()))


def test_help_lists_subcommands():
    r = run("--help")
    assert r.returncode == 0
    assert len(SUBCOMMANDS) > 20
    listed = set(re.findall(r"^    (\S+)", r.stdout, re.M))  # one row per subcommand
    assert listed == {path[0] for path in SUBCOMMANDS}


@pytest.mark.parametrize("path", SUBCOMMANDS, ids=" ".join)
def test_every_subcommand_has_help(path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([*path, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: hexbench {' '.join(path)} ")
    assert "-h, --help" in out


def test_decode_issue_example():
    r = run("decode", "--link", "pc", "2a15040804090000000023")
    assert r.returncode == 0 and "MCW" in r.stdout and "i=4 t1=8 t2=4 t3=9" in r.stdout


@pytest.mark.parametrize("args,needle", [
    (["decode", "--link", "pc", "zz"], "not hex"),
    (["decode", "--link", "nowhere", "00"], "no link 'nowhere'"),
    (["decode", "--link", "pc", "2a1"], "not hex"),
])
def test_decode_bad_input_exits_2(args, needle, capsys):
    assert main(args) == 2
    assert needle in capsys.readouterr().err


def test_decode_noise_is_reported(capsys):
    assert main(["decode", "--link", "pc", "ff", "2a15040804090000000023"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("noise ff") and out[1].startswith("command MCW")


def test_encode_then_decode(capsys):
    assert main(["encode", "SCW", "3", "8", "4", "9"]) == 0
    hexed = capsys.readouterr().out.strip()
    assert main(["decode", "--link", "pc", hexed]) == 0
    assert "SCW i=3 t1=8 t2=4 t3=9" in capsys.readouterr().out


def test_scenarios_bad_file_exits_2(tmp_path, capsys):
    p = tmp_path / "bad.toml"
    p.write_text("initial = [[0, 0]]\nseed = 'x'\n")
    assert main(["scenarios", str(p)]) == 2
    assert "bad.toml: line 2, key 'seed': expected an integer" in capsys.readouterr().err


def test_encode_refuses_missing_or_surplus_arguments(capsys):
    assert main(["encode", "MCW", "4", "8"]) == 2
    assert "MCW (21) takes 4 argument(s), MCW(i, t1, t2, t3); got 2" in capsys.readouterr().err
    assert main(["encode", "LOn", "1"]) == 2


def test_a_baud_rate_of_zero_is_refused(capsys):
    import pytest

    with pytest.raises(SystemExit) as exc:
        main(["hil", "--port", "loop://", "--baud", "0"])
    assert exc.value.code == 2 and "0 baud: expected 1..1000000" in capsys.readouterr().err


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"hexbench {version('hexbench')}"


def test_encode_refuses_a_value_equal_to_the_filler(capsys):
    """`Move 0 ...` was encoded because 0 is the PC frame's filler (issue 50, item 5)."""
    assert main(["encode", "Move", "0", "1", "1", "2", "1", "8", "4", "9"]) == 2
    assert capsys.readouterr().err.strip().endswith("dir=0: expected 1..2")

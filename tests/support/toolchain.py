"""Test-only: what the tests need installed, and what happens when it is not.

A test that needs a program (``needs_tools``), a file of a package, or a Python module
(``module``) is skipped where it is missing, and the skip is listed (``-rs`` in pyproject's
addopts). In CI (``CI`` set, or ``HEXBENCH_REQUIRE_TOOLS=1``, which ``make test`` and ``.ci/run``
set) it fails instead: a green CI run has run every test. ``tests/conftest.py`` takes the
hooks below.
"""

from __future__ import annotations

import importlib
import os
import shutil
from types import ModuleType
from typing import NoReturn

import pytest

#: Where a missing Debian package comes from.
SYSTEM = "make test installs it (.ci/system)"


def tools_required() -> bool:
    """CI, where every tool must be there: ``CI`` or ``HEXBENCH_REQUIRE_TOOLS`` set and not 0."""
    return any(os.environ.get(v, "") not in ("", "0") for v in ("CI", "HEXBENCH_REQUIRE_TOOLS"))


def missing(what: str, install: str = SYSTEM) -> NoReturn:
    """This test cannot run without ``what``: skip it, or in CI fail it."""
    text = f"needs {what} ({install})"
    if tools_required():
        pytest.fail(f"{text}: missing, and CI runs every test (CI / HEXBENCH_REQUIRE_TOOLS)",
                    pytrace=False)
    pytest.skip(text)


def needs_tools(*tools: str, install: str = SYSTEM) -> pytest.MarkDecorator:
    """``pytestmark = needs_tools("avrdude")``: the test runs these programs."""
    return pytest.mark.needs_tools(*tools, install=install)


def module(name: str, install: str = "pip install -e '.[test]'") -> ModuleType:
    """``import name``, or :func:`missing`."""
    try:
        return importlib.import_module(name)
    except ImportError:
        missing(f"the Python module {name}", install)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "needs_tools(*programs, install): the test runs these programs")


def pytest_runtest_setup(item: pytest.Item) -> None:
    for mark in item.iter_markers("needs_tools"):
        absent = [t for t in mark.args if shutil.which(t) is None]
        if absent:
            missing(" and ".join(absent), mark.kwargs.get("install", SYSTEM))


#: ``pytestmark = needs_avr`` for tests that build or run the C firmware.
needs_avr = needs_tools("avr-gcc")

"""hexbench's pytest plugin (entry point ``pytest11``): wire-protocol test fixtures."""

from __future__ import annotations


def pytest_addoption(parser) -> None:
    group = parser.getgroup("hexbench")
    group.addoption("--hexbench-target", default="virtual",
                    help="what the conformance suite talks to: 'virtual' (default) or "
                         "'serial:<url>'")

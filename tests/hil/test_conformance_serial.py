"""The conformance suite (hexbench.conformance) with ``--hexbench-target serial:<pty>``
against stand-ins, both profiles, in four shards that run in the background (conftest)."""

from __future__ import annotations

import re


def test_conformance_suite_passes_over_a_serial_port(hil_rig, shard_index: int):
    """``shard_index`` is parametrized by conftest.py (one per shard)."""
    shard = hil_rig.shards[shard_index]
    assert shard.done.wait(hil_rig.shard_timeout_s + 60), f"shard {shard_index} still running"
    assert shard.returncode == 0, shard.output
    summary = shard.output.strip().splitlines()[-1]
    assert re.search(r"\b\d+ passed", summary), summary
    assert "failed" not in summary and "error" not in summary, summary
    # what skips, skips with a reason naming the serial target
    for line in shard.output.splitlines():
        if line.startswith("SKIPPED") and "pytest_plugin" in line:
            assert "serial:" in line, line

"""The conformance suite (hexbench.conformance) with ``--hexbench-target serial:<pty>``
against stand-ins, both profiles, in four shards that run in the background (conftest); the
v2 stand-ins' debug UART1 shows that every test leaves every actuator off."""

from __future__ import annotations

import json
import re
from xml.etree import ElementTree


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


def test_conformance_suite_leaves_every_actuator_off(hil_rig, v2_shard_index: int):
    """Against a v2 stand-in whose debug UART1 is given (``--hexbench-debug``): after every test
    of the suite, the board's last actuator report shows every solenoid and magnet off. The
    tests that energise them (JxOpen, JxOpenAll, SxP, SxN) saw the board report them on and off."""
    shard = hil_rig.shards[v2_shard_index]
    assert shard.done.wait(hil_rig.shard_timeout_s + 60), f"shard {v2_shard_index} still running"
    assert shard.junit.exists(), shard.output
    cases = ElementTree.parse(shard.junit).getroot().iter("testcase")
    seen = 0
    for case in cases:
        name = f"{case.get('classname')}.{case.get('name')}"
        props = {p.get("name"): p.get("value") for p in case.iter("property")}
        assert "hexbench_actuators" in props, f"{name}: no actuator state recorded"
        last = json.loads(props["hexbench_actuators"])
        if last is not None:  # null: no report yet, the board as it booted (all off)
            assert not any(last["joints_open"]) and not any(last["magnets"]), (name, last)
        if "test_control_code_ack_and_port_bits" in name:  # on, then off: two reports at least
            assert int(props["hexbench_actuator_reports"]) >= 2, (name, props)
            seen += 1
    if "not" in shard.select:
        assert seen == 5, f"{seen} actuator tests in {shard.select!r}"

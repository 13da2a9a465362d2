"""A wall-clock fleet watches its own lag (module_sim.fleet.LagWatch): a clock thread held up
on purpose (a handler that sleeps 300 ms: the thing under test) gives a ``lag`` event, one
console line and a failure line that names it; a run that keeps up gives none.

The tests run beside others on a loaded machine (xdist on two cores), where a clock thread is
sometimes late by tens of milliseconds for real: they raise the threshold to 120 ms so that
only the deliberate block counts as lag."""

from __future__ import annotations

import gc
import re
import time

import pytest

from bus.clock import WallClock
from bus.scenario import load
from bus.session import SessionOptions
from bus.transport import Bus
from hexbench.cli import main
from hexbench.fleet import LagNotice
import module_sim.fleet
from module_sim.fleet import Fleet

BLOCK_S = 0.3  # what the blocking handler sleeps: thirty ticks
LAG_THRESHOLD_NS = 120_000_000  # in these tests (module_sim.fleet's is 20 ms)


@pytest.fixture(autouse=True)
def threshold(monkeypatch):
    monkeypatch.setattr(module_sim.fleet, "LAG_THRESHOLD_NS", LAG_THRESHOLD_NS)


@pytest.fixture(autouse=True)
def fresh_heap():
    """The heap of the tests before, out of the collector's reach: in a long test process a full
    collection over it stops the clock thread for 100 ms and more, a lag a fresh ``hexbench``
    process would not have."""
    gc.collect()
    gc.freeze()
    yield
    gc.unfreeze()


def _wall_fleet(name: str, *, block_at_s: list[float], seconds: float = 1.0) -> tuple[list[dict], list[str]]:
    """``pair`` on the wall clock for ``seconds``, with a handler sleeping BLOCK_S at each of
    ``block_at_s``: its ``lag`` events and its console lines."""
    clock = WallClock()
    bus = Bus(clock, name, options=SessionOptions(isolated=True))
    try:
        events: list[dict] = []
        lines: list[str] = []
        bus.subscribe_json(bus.keys.event("fleet"), lambda k, d: events.append(d))
        LagNotice(bus, lines.append)
        Fleet(bus, load("pair")).power_up()
        for t in block_at_s:
            clock.call_later(int(t * 1e9), time.sleep, BLOCK_S)
        clock.run(timeout_s=seconds)
        return events, lines
    finally:
        bus.close()


def test_a_blocked_clock_thread_gives_one_lag_event_and_one_line():
    events, lines = _wall_fleet("lagblocked", block_at_s=[0.3, 0.35], seconds=1.5)
    (e,) = events  # both blocks in one span: one event with the span's worst
    assert e["kind"] == "lag" and e["src"] == "fleet" and e["threshold_ns"] == LAG_THRESHOLD_NS
    assert 0.9 * BLOCK_S * 1e9 <= e["late_ns"] == max(e["timer_late_ns"], e["delivery_late_ns"]) < 1.0e9
    (line,) = lines
    ms = re.fullmatch(r"lag: the fleet ran (\d+) ms behind the wall clock \(timers up to \d+ ms late, "
                      r"deliveries \d+ ms; more than 120 ms is lag\): the machine is overloaded, and a "
                      r"timeout from now on may be this rather than a protocol fault", line)
    assert ms and int(ms.group(1)) == round(e["late_ns"] / 1e6), line


def test_the_console_says_it_once_in_a_while():
    events, lines = _wall_fleet("lagtwice", block_at_s=[0.2, 1.5], seconds=2.5)
    assert len(events) == 2  # a second span, a second event ...
    assert len(lines) == 1  # ... but the console said it once


def test_a_fleet_that_keeps_up_says_nothing():
    events, lines = _wall_fleet("lagnone", block_at_s=[])
    assert events == [] and lines == []


def test_lateness_counts_from_when_the_clock_runs():
    """Work that waited for its owner to run the clock (a planner planning between its waits)
    is not lag; work held up by a handler is."""
    clock = WallClock()
    clock.call_later(0, lambda: None)
    clock.post(lambda: None)
    time.sleep(BLOCK_S)  # nobody runs the clock
    clock.run(timeout_s=0.05)
    timers, deliveries = clock.take_lateness()
    assert timers < LAG_THRESHOLD_NS and deliveries < LAG_THRESHOLD_NS
    clock.call_later(0, time.sleep, BLOCK_S)
    clock.call_later(0, lambda: None)
    clock.call_later(0, clock.post, lambda: None)
    clock.run(timeout_s=0.3)
    timers, deliveries = clock.take_lateness()
    assert timers >= BLOCK_S * 1e9 * 0.9 and deliveries < LAG_THRESHOLD_NS
    assert clock.take_lateness() == (0, 0)  # taken


@pytest.fixture
def quick_boot(monkeypatch):
    """A wall run whose boot wait is 1.5 s instead of 9 s."""
    monkeypatch.setattr("planner_svc.bringup.BOOT_S", 1.5)


def _failing_run(tmp_path, capsys) -> tuple[int, str]:
    """``hexbench run pair --clock wall`` with a script whose expectation is never met."""
    script = tmp_path / "never.txt"
    script.write_text("expect ack 99 timeout=0.5\n")
    code = main(["run", "pair", "--clock", "wall", "--isolated", "--fleet", f"lagrun{id(script)}",
                 "--planner", f"script:{script}"])
    return code, capsys.readouterr().out


def test_a_run_that_fails_after_lag_names_it(tmp_path, capsys, monkeypatch, quick_boot):
    power_up = Fleet.power_up

    def power_up_then_block(self, *args, **kwargs):
        power_up(self, *args, **kwargs)
        self.bus.clock.call_later(int(0.3e9), time.sleep, BLOCK_S)
    monkeypatch.setattr(Fleet, "power_up", power_up_then_block)
    code, out = _failing_run(tmp_path, capsys)
    assert code == 1
    assert len(re.findall(r"^lag: the fleet ran \d+ ms behind the wall clock", out, re.M)) == 1, out
    failed = out.strip().splitlines()[-1]
    assert re.fullmatch(r"script:.*: FAILED: .*ack.*; steps 0, .* \(the fleet ran up to \d+ ms behind the "
                        r"wall clock: the machine was overloaded\)", failed), failed


def test_a_run_that_fails_without_lag_names_none(tmp_path, capsys, quick_boot):
    code, out = _failing_run(tmp_path, capsys)
    assert code == 1
    failed = out.strip().splitlines()[-1]
    assert "FAILED" in failed
    # the failure line names lag exactly when the console said the fleet lagged (which, with
    # nothing held up on purpose, a machine this loaded should not make it do)
    said_lag = re.search(r"^lag: the fleet ran", out, re.M) is not None
    assert ("behind the wall clock" in failed) == said_lag, out
    assert not said_lag, out

"""Tests on the wall clock (``@pytest.mark.wall_clock``): they pass, or the machine was too slow
for them and they fail with one line that says how slow.

A fleet on the wall clock says when it falls behind (``lag: the fleet ran N ms behind the wall
clock``, :class:`hexbench.fleet.LagNotice` from :class:`module_sim.fleet.LagWatch`) in the
output a test reads (:func:`heard`, or its failure message), and this process watches its own
timers the same way while each such test runs. A failure that comes
with lag past the watcher's threshold is reported as that one line (the load average with it);
one without is reported as it is: a fault of the program, not of the machine.
"""

from __future__ import annotations

import os
import re
import threading
import time

import pytest

MARKER = "wall_clock"
#: the fleet's lag lines, as LagNotice says them (and its failure line's "ran up to")
_FLEET_LAG = re.compile(r"the fleet ran (?:up to )?(\d+) ms behind the wall clock")
_TICK_S = 0.01


class TimerLag:
    """How late this process's own 10 ms timers ran while a test went (the LagWatch idea)."""

    def __init__(self) -> None:
        self.worst_ns = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="wall-clock-lag", daemon=True)
        self._thread.start()

    def _watch(self) -> None:
        due = time.monotonic_ns() + int(_TICK_S * 1e9)
        while not self._stop.wait(max(0.0, (due - time.monotonic_ns()) / 1e9)):
            self.worst_ns = max(self.worst_ns, time.monotonic_ns() - due)
            due = time.monotonic_ns() + int(_TICK_S * 1e9)

    def stop(self) -> int:
        self._stop.set()
        self._thread.join(timeout=1)
        return self.worst_ns


#: the output of the runs the current test read (:func:`heard`): their lag lines count
_HEARD: list[str] = []


def heard(output: str) -> str:
    """A wall-clock run's output, as the test reads it: its lag lines name the machine's lag
    if the test fails (whatever its assertion shows). Returns ``output``."""
    _HEARD.append(output)
    return output


def fleet_lag_ms(text: str) -> int:
    """The worst lag a fleet said in ``text`` (a run's output in a failure message), or 0."""
    return max((int(ms) for ms in _FLEET_LAG.findall(text)), default=0)


def too_slow(fleet_ms: int, timers_ns: int) -> str | None:
    """The one line for a failure under lag, or None when neither watcher saw lag."""
    from module_sim.fleet import LAG_THRESHOLD_NS

    limit_ms = LAG_THRESHOLD_NS / 1e6
    if fleet_ms <= limit_ms and timers_ns <= LAG_THRESHOLD_NS:
        return None
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    fleet = f"the fleet ran up to {fleet_ms} ms behind the wall clock, " if fleet_ms > limit_ms else ""
    return (f"wall clock: the machine was too slow for this test: {fleet}this process's timers up to "
            f"{timers_ns / 1e6:.0f} ms late (more than {limit_ms:.0f} ms is lag); load average {load}")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    """Watch this process's timers from the test's setup to its teardown."""
    watch = TimerLag() if item.get_closest_marker(MARKER) is not None else None
    if watch is not None:
        item.stash[_WATCH] = watch
        _HEARD.clear()
    yield
    if watch is not None:
        watch.stop()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    outcome = yield
    watch = item.stash.get(_WATCH, None)
    report = outcome.get_result()
    if watch is None or not report.failed:
        return
    line = too_slow(fleet_lag_ms("\n".join([str(report.longrepr), *_HEARD])), watch.worst_ns)
    if line is not None:
        report.longrepr = line


_WATCH = pytest.StashKey[TimerLag]()

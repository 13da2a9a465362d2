"""Wall-clock tests (``@pytest.mark.wall_clock``, tests/support/wall_clock.py): a failure with
the machine's lag is one line naming it; a failure without lag is reported as it is."""

from __future__ import annotations

pytest_plugins = ["pytester"]

_TESTS = '''
import pytest

@pytest.mark.wall_clock
def test_lagged():
    out = "bring-up: ...\\nlag: the fleet ran 85 ms behind the wall clock (timers up to 85 ms late)\\n"
    assert out.count("no divergence") == 2, out

@pytest.mark.wall_clock
def test_lagged_run_read_by_the_test():
    from wall_clock import heard
    heard("lag: the fleet ran 120 ms behind the wall clock (timers up to 120 ms late)")
    assert not ["twin-diverged"]  # its message does not show the run's output

@pytest.mark.wall_clock
def test_broken():
    assert 1 + 1 == 3, "a fault of the program"

def test_unmarked():
    assert False, "lag: the fleet ran 85 ms behind the wall clock"
'''


def test_a_wall_clock_failure_under_lag_is_one_line_naming_it(pytester):
    pytester.makeconftest("from wall_clock import pytest_runtest_makereport, pytest_runtest_protocol\n")
    pytester.makepyfile(test_it=_TESTS)
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider", "-q")
    result.assert_outcomes(failed=4)
    out = result.stdout.str()
    lagged = [line for line in out.splitlines() if line.startswith("wall clock: ")]
    assert len(lagged) == 2
    assert ("the machine was too slow for this test: the fleet ran up to 85 ms behind the wall "
            "clock" in lagged[0] and "load average" in lagged[0])
    assert "the fleet ran up to 120 ms behind the wall clock" in lagged[1]
    assert "a fault of the program" in out and "assert (1 + 1) == 3" in out  # no lag: as it is
    assert "test_unmarked" in out and "AssertionError: lag: the fleet ran" in out  # not marked

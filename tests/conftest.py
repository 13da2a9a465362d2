"""Shared test configuration."""

from hypothesis import HealthCheck, settings

# A missing tool skips a test, or fails it in CI (tests/support/toolchain.py).
from toolchain import pytest_configure, pytest_runtest_setup  # noqa: F401  (pytest hooks)
# A wall-clock test passes, or fails with one line naming the machine's lag.
from wall_clock import pytest_runtest_makereport, pytest_runtest_protocol  # noqa: F401

settings.register_profile("ci", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci")

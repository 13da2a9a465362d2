"""Test-only: what the firmware tests need installed."""

from __future__ import annotations

import shutil

import pytest

#: ``pytestmark = needs_avr`` for tests that build or run the C firmware.
needs_avr = pytest.mark.skipif(shutil.which("avr-gcc") is None,
                               reason="needs the AVR toolchain (make test installs it)")

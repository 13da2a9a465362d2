"""hil.pty: the device end of a pseudo-terminal answers pyserial's ``in_waiting`` and
``read(size)`` as a serial port does (the bridge and the stand-in read ``in_waiting or 1``)."""

from __future__ import annotations

import time

import pytest
import serial

from hil.pty import Pty


DATA = bytes(range(256)) + b"tail" * 25  # 356 bytes, more than the 256 a read took before


@pytest.fixture
def line(tmp_path):
    """(the pty, pyserial's port on its other end)"""
    pty = Pty(tmp_path / "ttyT")
    port = serial.serial_for_url(pty.path, baudrate=300, timeout=1)
    try:
        yield pty, port
    finally:
        port.close()
        pty.close()


def test_in_waiting_counts_what_the_other_end_wrote(line):
    pty, port = line
    assert pty.in_waiting == 0
    port.write(DATA)
    port.flush()
    deadline = time.monotonic() + 5
    while pty.in_waiting < len(DATA) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert pty.in_waiting == len(DATA)
    pty.read(10)
    assert pty.in_waiting == len(DATA) - 10


def test_read_takes_at_most_size(line):
    pty, port = line
    port.write(DATA)
    port.flush()  # on a pty the bytes are there once written
    assert pty.read(10) == DATA[:10]
    assert pty.read() == DATA[10:11]  # size 1 by default, as pyserial
    assert pty.read(len(DATA)) == DATA[11:]
    assert pty.read(5) == b""  # nothing there: b"" after the timeout


def test_a_hung_up_pty_has_nothing_waiting(tmp_path):
    pty = Pty(tmp_path / "ttyH")
    pty.hangup()
    try:
        assert pty.in_waiting == 0 and pty.read(4) == b""
    finally:
        pty.close()

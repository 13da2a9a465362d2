"""How the v2 comm board reads a frame from the PC: ``*``, nine bytes, ``#`` (docs/protocol.md).

The C program does the same in ``co_listen`` (firmware/src/comm.c). The thesis-2009 board
reads ``*`` and nine bytes; the control board reads its relay frames in its own ``listen``.
"""

from __future__ import annotations

from bus.codec import END, START
from bus.timing import FRAME_BYTE_TICKS

from .avr import Program, Rx, Uart

_START, _END = START[0], END[0]


def read_frame(uart: Uart, length: int) -> Program:
    """What lies between the ``*`` and ``#`` of the next frame of ``length`` bytes, or None
    when what was read was not one.

    After ``*`` each byte must come within ``FRAME_BYTE_TICKS``: a silence ends the frame, so
    a frame sent after one is read in step whatever the bytes before it (the rest of a frame
    lost to an overrun, a ``*`` inside a damaged frame's arguments). A body not followed by
    ``#`` was garbage with a ``*`` in it: reading goes on from the next ``*`` inside it."""
    while (yield Rx(uart)) != _START:
        pass
    body, got = length - 2, []
    while True:
        b = yield Rx(uart, FRAME_BYTE_TICKS, tell_timeout=True)
        if b is None:
            return None
        got.append(b)
        if len(got) <= body:
            continue
        if got[body] == _END:
            return got[:body]
        if _START not in got:
            return None
        got = got[got.index(_START) + 1:]

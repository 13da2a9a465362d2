"""Clocks and wire timing of the ATmega162 boards (spec §3).

Both MCUs run at 1 MHz; Timer0 overflows every 9.984 ms and increments the tick
counter ``ts`` that every wait in the firmware counts. All UARTs are 8N1, so a
byte occupies ten bit times on the wire.
"""

from __future__ import annotations

import math
from enum import Enum

NS_PER_S = 1_000_000_000

#: Timer0 overflow period: prescaler 64, reload 0x64 -> 156 counts of 64 us.
TICK_NS = 9_984_000

#: 8N1: start bit, eight data bits, stop bit.
BITS_PER_BYTE = 10

#: The thesis allows this gap after every IR multiplexer change (§3.4.3).
IR_MUX_GAP_NS = 380_000

#: Control board boot: DelayXts(10) before anything else.
BOOT_SETTLE_TICKS = 10

#: The comm board waits this many ticks for the control board's echo.
ECHO_TIMEOUT_TICKS = 250

#: The substrate (S=1) waits this long before its ACK so two modules do not answer at once.
SUBSTRATE_ACK_DELAY_TICKS = 100

#: Handshake retry period ('R' repeated until the peer answers).
HANDSHAKE_RETRY_TICKS = 10

#: A listener waits this long per side for the '*' of MSG1 (Appendix A `Localize`).
LOCALIZE_LISTEN_TICKS = 150

#: The longest a coil may stay energised without a pause (ours, both profiles): past it the
#: control board switches it off and reports it (``LIM``, docs/protocol.md). A magnet (24 V,
#: 2 A: 48 W) is on only inside a rotation, at most t2 + t3 = 510 ticks with the largest
#: arguments (0.13 s at the thesis timing): 8 s catches one forgotten on. A solenoid (5 V,
#: 0.5 A) is held open by the PC while a neighbour moves away: every release of a move is
#: opened before it and closed after it, one frame at a time at 300 baud (up to about 35 s for
#: a mobile with five neighbours), so its limit is a minute.
MAGNET_ON_LIMIT_TICKS = 801
SOLENOID_ON_LIMIT_TICKS = 6010

#: SelfTest (ours): each actuator on this long, then off as long, one after another.
SELFTEST_PULSE_TICKS = 10


class Baud(int, Enum):
    """Baud rates of the three kinds of link (spec §3, table of links)."""

    UART0 = 4800  # control <-> comm, UBRR 12
    DEBUG = 4800  # control board UART1 to a PC terminal
    IR = 300  # comm board UART1 through the IR multiplexer, UBRR 207
    IR_FAST = 62_500  # the maximum §4.3.4 uses for its localization timing


def byte_time_ns(baud: int) -> int:
    """Time one 8N1 byte occupies the wire at ``baud`` (rounded to the ns)."""
    return (BITS_PER_BYTE * NS_PER_S + baud // 2) // baud


def wire_time_ns(n_bytes: int, baud: int) -> int:
    """Time ``n_bytes`` back-to-back bytes occupy the wire."""
    return n_bytes * byte_time_ns(baud)


def ticks_ns(ticks: int) -> int:
    return ticks * TICK_NS


def localize_slot_ticks(baud: int) -> int:
    """v2 localization: one slot carries preamble, role and MSG1 (15 bytes) plus guards."""
    return math.ceil(15 * byte_time_ns(baud) / TICK_NS) + 3


def localize_step_ticks(baud: int) -> int:
    """v2 localization: a step is 6 listener windows of 6 sender slots."""
    return 36 * localize_slot_ticks(baud)

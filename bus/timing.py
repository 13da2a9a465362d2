"""Clocks and wire timing of the ATmega162 boards (spec §3).

Both MCUs run at 1 MHz; Timer0 overflows every 9.984 ms and increments the tick
counter ``ts`` that every wait in the firmware counts. All UARTs are 8N1, so a
byte occupies ten bit times on the wire.
"""

from __future__ import annotations

import math
from enum import Enum

NS_PER_S = 1_000_000_000

#: Timer0 tick period: prescaler 64, CTC to 155 -> 156 counts of 64 us.
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

#: v2: once a board has read a frame's '*' (the PC's frame on IR, a relay frame on UART0) it
#: waits this long for each further byte; a longer silence ends the frame unread. A frame goes
#: out in one burst (at 300 baud a byte every 3.3 ticks, on UART0 one every 0.2), so a silence
#: inside one means its rest was lost (the board was busy and its input overran) or its '*'
#: was noise: the next frame after a silence is read in step whatever its arguments hold.
FRAME_BYTE_TICKS = 10

# -- the programs' own shows and waits (Appendix A's DelayXts and loop counts) -------------
# Both programs take these from here: the Python model by name, the C firmware through
# hexbot_gen.h (bus.cheader). A call with a bare number fails tests/firmware/test_header.py.

#: Comm board boot: LFlash1 (the control board said 'R'), LFlash2 (it listens) and LColor
#: (before COMM_LST), each this many rounds of this many ticks per phase.
BOOT_FLASH_ROUNDS = 3
BOOT_FLASH_TICKS = 10
#: Comm board boot, after CTR_LST: LCircle, one round of this many ticks per phase.
BOOT_CIRCLE_ROUNDS = 1
BOOT_CIRCLE_TICKS = 5

#: Control board boot, after BOOT_SETTLE_TICKS: JTest, the joints click once ("ready").
BOOT_JTEST_ROUNDS = 1
BOOT_JTEST_TICKS = 5

#: LYref: the side that faces global +Y shows positive, then negative, this long each.
YREF_FLASH_TICKS = 10
#: Ref() and a localization report show the orientation with this many LYref(0).
YREF_SHOWS = 3

#: Appendix A's Localize, a localized module: this many rounds over its sides 2 and 3,
#: sending MSG1 on each this many times, each after this many ticks.
THESIS_LOCALIZE_ROUNDS = 6
THESIS_LOCALIZE_REPEATS = 2
THESIS_LOCALIZE_SEND_TICKS = 5
#: Appendix A's Localize, a listener that heard no MSG1: LCircle, one round of 5 ticks.
LOCALIZE_FAILED_CIRCLE_ROUNDS = 1
LOCALIZE_FAILED_CIRCLE_TICKS = 5

#: v2 localization: a sender waits this long after selecting a side, more than the
#: multiplexer gap (IR_MUX_GAP_NS); the listener is already there.
LOCALIZE_MUX_SETTLE_TICKS = 2
#: v2 localization: after the '*' of MSG1 a listener waits this long for each further byte.
LOCALIZE_BYTE_TICKS = 10
#: v2 localization: what one sender slot carries (preamble, one role prefix, '*' and
#: MSG1's seven bytes) and its guard: the settle wait, and a tick for where in its tick a
#: listener's window starts.
LOCALIZE_SLOT_BYTES = 15
LOCALIZE_SLOT_GUARD_TICKS = 3

#: The rotation timing (t1, t2, t3) of Appendix A's CW/CCW tests (spec §7), which the PC's
#: ``Move`` and a Walter round's actuation both use.
THESIS_ROTATION_TIMING = (8, 4, 9)

# -- v2 distributed reconfiguration: one Walter round (docs/protocol.md), ticks from the beat --
# The parts below make the round's layout (the walter_* functions); the programs wait for the
# layout's instants (WALTER_*_AT in the header), never for a part alone.
#: A side window: select the side, settle, the request (4 bytes) and its answer (3), a guard
#: (bus.codec.WALTER_REQUEST_LEN + WALTER_ANSWER_LEN).
WALTER_MUX_SETTLE_TICKS = 2
WALTER_SIDE_MSG_BYTES = 7
WALTER_WINDOW_GUARD_TICKS = 3
#: After the last window, before the actuation: a JxOpen a mover relayed in the last window
#: has left the control board's debug UART (its ACK and MSG lines, about 50 ms).
WALTER_RELAY_GUARD_TICKS = 8
#: A second mover about a substrate that already turns one from the side next to it starts
#: this much after the actuation: the substrate's first rotation is over (relay and debug lines
#: about 6 ticks, t1 + t2 + t3 = 21), so its two repelling sides are never on together.
WALTER_LATE_TICKS = 32
#: Holders close their pins this much after the late slot: after its break-away (relay, t1
#: and 3 ticks: about 20 ticks), before the rotation's end.
WALTER_HOLD_TICKS = 25
#: The actuation, from its start: the late slot, its rotation (about 27 ticks), the 220 ms
#: turn to the arrival, the holders' closing relay and the switches.
WALTER_ACTUATION_TICKS = 70
#: The log line's relay and the control board's printing of it, before the busy slot.
WALTER_LOG_TICKS = 8
WALTER_BUSY_GUARD_TICKS = 2


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
    """v2 localization: one sender slot, its line (LOCALIZE_SLOT_BYTES) and its guard."""
    return math.ceil(LOCALIZE_SLOT_BYTES * byte_time_ns(baud) / TICK_NS) + LOCALIZE_SLOT_GUARD_TICKS


def localize_window_ticks(baud: int) -> int:
    """v2 localization: a listener window is 6 sender slots, one per side."""
    return 6 * localize_slot_ticks(baud)


def localize_step_ticks(baud: int) -> int:
    """v2 localization: a step is 6 listener windows, one per side."""
    return 6 * localize_window_ticks(baud)


def walter_window_ticks(baud: int) -> int:
    """A Walter round's side window: settle, request and answer, guard."""
    return (math.ceil(WALTER_SIDE_MSG_BYTES * byte_time_ns(baud) / TICK_NS)
            + WALTER_MUX_SETTLE_TICKS + WALTER_WINDOW_GUARD_TICKS)


def walter_actuation_at(baud: int) -> int:
    """Ticks from the beat to the actuation: six windows and the relay guard."""
    return 6 * walter_window_ticks(baud) + WALTER_RELAY_GUARD_TICKS


def walter_late_at(baud: int) -> int:
    """Ticks from the beat to the late slot of a second mover about one substrate."""
    return walter_actuation_at(baud) + WALTER_LATE_TICKS


def walter_hold_end_at(baud: int) -> int:
    """Ticks from the beat to when holders close their pins again."""
    return walter_late_at(baud) + WALTER_HOLD_TICKS


def walter_log_at(baud: int) -> int:
    return walter_actuation_at(baud) + WALTER_ACTUATION_TICKS


def walter_busy_at(baud: int) -> int:
    return walter_log_at(baud) + WALTER_LOG_TICKS


def walter_round_ticks(baud: int) -> int:
    """Ticks from the beat to the round's end: the busy byte has left every module."""
    return (walter_busy_at(baud) + math.ceil(byte_time_ns(baud) / TICK_NS)
            + WALTER_BUSY_GUARD_TICKS)

"""The ATmega162 as a programmer sees it: signature, memories, the fuses we write, and the
board-kind record each image checks before it drives a pin.

Both HexBot boards carry the same part, so nothing on the chip tells a control board from a
communication board. ``hexbench firmware flash --board KIND`` writes a four-byte record at
the start of the EEPROM; each image reads it at power-up, before it makes any pin an
output, and runs only on the board it was built for (docs/firmware.md, "Each image knows
its board"). The high fuse keeps the EEPROM through a chip erase (EESAVE), so the record
survives every later flash.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

#: avrdude's part name, the device signature (datasheet §"Signature bytes").
AVRDUDE_PART = "m162"
SIGNATURE = bytes((0x1E, 0x94, 0x04))
FLASH_SIZE = 16 * 1024
FLASH_PAGE = 128
EEPROM_SIZE = 512


@dataclass(frozen=True)
class Fuses:
    low: int
    high: int
    extended: int

    def avrdude_args(self) -> list[str]:
        return [f"-Ulfuse:w:0x{self.low:02X}:m", f"-Uhfuse:w:0x{self.high:02X}:m",
                f"-Uefuse:w:0x{self.extended:02X}:m"]


#: Table 3-6: internal 8 MHz RC / 8 = 1 MHz (CKDIV8, low 0x62); high 0xD9 turns JTAG off so
#: PC4..PC7 are ordinary port pins (the comm board's LEDs, the control board's DIP
#: switches) and keeps SPI programming on; extended 0xFF (BOD off). We program EESAVE as
#: well (high 0xD1): a chip erase then keeps the EEPROM and its board-kind record.
THESIS_FUSES = Fuses(low=0x62, high=0xD9, extended=0xFF)
FUSES = Fuses(low=0x62, high=0xD1, extended=0xFF)

#: Serial programming: each instruction is 4 bytes, 32 SCK periods; a byte of flash or EEPROM,
#: read or loaded, is one instruction. Then the chip's own waits before the next write
#: (datasheet, "Minimum Wait Delay Before Writing the Next Flash or EEPROM Location").
ISP_INSTRUCTION_BITS = 32
T_WD_FLASH_S = 4.5e-3  # a flash page
T_WD_EEPROM_S = 9.0e-3  # an EEPROM byte
T_WD_FUSE_S = 4.5e-3  # a fuse or lock byte
T_WD_ERASE_S = 9.0e-3  # a chip erase

#: Lock bits (datasheet, "Lock Bit Protection Modes"), 0 = programmed: LB1 alone (mode 2)
#: stops further programming; LB2 as well (mode 3) stops verification too, so flash and
#: EEPROM then read back as a pattern, not what they hold. Only a chip erase clears them.
LOCK_LB1, LOCK_LB2 = 0x01, 0x02


def reads_disabled(lock: int) -> bool:
    """A chip with this lock byte does not let a programmer read its flash and EEPROM."""
    return not lock & LOCK_LB2


def writes_disabled(lock: int) -> bool:
    """A chip with this lock byte takes no write (flash, EEPROM, fuses) before a chip erase."""
    return not lock & LOCK_LB1


#: A 1 MHz target needs the ISP clock below 250 kHz (a quarter of the CPU clock): avrdude's
#: ``-B`` bit clock period in microseconds; 8 us = 125 kHz leaves a factor of two.
ISP_BITCLOCK_US = 8


class BoardKind(IntEnum):
    """The kind byte of the record (the same numbers as ``BOARD_CONTROL``/``BOARD_COMM`` in
    the firmware's hexbot.h)."""

    CONTROL = 1
    COMM = 2


#: EEPROM bytes 0..3: "HB", the kind, and the kind's complement (an erased EEPROM, 0xFF
#: everywhere, or a stray write is never read as a kind).
BOARD_RECORD_ADDR = 0
BOARD_RECORD_MAGIC = b"HB"
BOARD_RECORD_LEN = 4


def board_record(kind: BoardKind) -> bytes:
    """The four EEPROM bytes that name ``kind``."""
    return BOARD_RECORD_MAGIC + bytes((int(kind), 0xFF ^ int(kind)))


def read_board_record(eeprom: bytes) -> BoardKind | None:
    """The kind an EEPROM image names, or None (erased, foreign or damaged record)."""
    rec = eeprom[BOARD_RECORD_ADDR:BOARD_RECORD_ADDR + BOARD_RECORD_LEN]
    if len(rec) != BOARD_RECORD_LEN or rec[:2] != BOARD_RECORD_MAGIC or rec[2] ^ rec[3] != 0xFF:
        return None
    try:
        return BoardKind(rec[2])
    except ValueError:
        return None

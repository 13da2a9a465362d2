"""Pin maps of both boards (thesis Tables 3-3, 3-4, 3-5; Appendix A).

Indexed by joint/side number 1..6. The virtual boards, the world's physics, the
replay and the C firmware's generated header all read these tables.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, order=True)
class Pin:
    port: str  # "A".."E"
    bit: int  # 0..7

    @property
    def mask(self) -> int:
        return 1 << self.bit

    def __str__(self) -> str:
        return f"P{self.port}{self.bit}"

    @classmethod
    def parse(cls, text: str) -> "Pin":
        """``"PB6"`` -> Pin("B", 6)."""
        if len(text) != 3 or text[0] != "P" or text[1] not in "ABCDE" or text[2] not in "01234567":
            raise ValueError(f"not a pin name: {text!r}")
        return cls(text[1], int(text[2]))


def _pins(*names: str) -> dict[int, Pin]:
    return {k: Pin.parse(n) for k, n in enumerate(names, start=1)}


PORTS = ("A", "B", "C", "D", "E")

# --- control board (outputs active high) --------------------------------------
#: Joint solenoid J1..J6 (set = energised = joint open).
JOINT = _pins("PA2", "PA3", "PA5", "PA4", "PA0", "PA1")
#: Positive relay of the side magnet S1..S6.
MAGNET_POS = _pins("PB0", "PD3", "PB6", "PD4", "PB1", "PB7")
#: Negative relay of the side magnet S1..S6.
MAGNET_NEG = _pins("PD6", "PD5", "PD7", "PB4", "PB5", "PD2")
#: DIP switches (inputs): the module's hardware id in protocol v2.
DIP_PORT = "C"
#: Pins SxOffAll leaves alone: the two UARTs' RX/TX.
CONTROL_UART_PINS = (Pin.parse("PB2"), Pin.parse("PB3"), Pin.parse("PD0"), Pin.parse("PD1"))

# --- communication board (LEDs active low: cleared bit = LED on) ---------------
LED_POS = _pins("PA6", "PE1", "PC6", "PC3", "PC1", "PD6")
LED_NEG = _pins("PA5", "PE0", "PC7", "PC4", "PC0", "PD5")
LED_JOINT = _pins("PD7", "PA7", "PE2", "PC5", "PC2", "PD4")

#: IR multiplexer selector bits: channel number = A + 2B + 4C.
IR_SEL_A, IR_SEL_B, IR_SEL_C = Pin.parse("PA2"), Pin.parse("PA1"), Pin.parse("PA0")
IR_SEL_MASK = IR_SEL_A.mask | IR_SEL_B.mask | IR_SEL_C.mask

#: Optical switches (inputs, active high): a neighbour touches body side 1..6. The thesis
#: names no pins for them (§4.3.4 only says they exist); these are free pins of the comm
#: board, our choice for the v2 firmware (docs/firmware.md).
OPTICAL_SWITCH = _pins("PB0", "PB1", "PB4", "PB5", "PB6", "PB7")

#: Transceiver number (0 = centre, 1..6 = body side) on each CD4051 channel Y0..Y6.
IR_CHANNEL_TRANSCEIVER = (1, 6, 0, 2, 5, 3, 4)
#: Inverse: transceiver -> CD4051 channel (what ``IrSel(i)`` selects).
IR_TRANSCEIVER_CHANNEL = {t: ch for ch, t in enumerate(IR_CHANNEL_TRANSCEIVER)}
CENTRE = 0


def ir_select_bits(transceiver: int) -> int:
    """PORTA bits (within ``IR_SEL_MASK``) that ``IrSel(transceiver)`` leaves set."""
    ch = IR_TRANSCEIVER_CHANNEL[transceiver]
    return ((IR_SEL_A.mask if ch & 1 else 0) | (IR_SEL_B.mask if ch & 2 else 0)
            | (IR_SEL_C.mask if ch & 4 else 0))


def ir_selected(porta: int) -> int | None:
    """Transceiver the multiplexer connects for a PORTA value (None: channel Y7, unwired)."""
    ch = ((1 if porta & IR_SEL_A.mask else 0) | (2 if porta & IR_SEL_B.mask else 0)
          | (4 if porta & IR_SEL_C.mask else 0))
    return IR_CHANNEL_TRANSCEIVER[ch] if ch < len(IR_CHANNEL_TRANSCEIVER) else None


def fold(i: int) -> int:
    """The firmware's ``while (i<1) i+=6; while (i>6) i-=6;`` for a joint/side index."""
    return (i - 1) % 6 + 1

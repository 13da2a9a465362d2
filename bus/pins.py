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
#: DIP switches (inputs): the module's hardware id in protocol v2. Each switch closes its pin
#: to ground when ON, against the internal pull-up, so the id is the complement of PINC (bit k
#: of the id = switch k+1 ON); all switches open reads 0, which is no id.
DIP_PORT = "C"
DIP_ACTIVE_LOW = True
#: Pins SxOffAll leaves alone: the two UARTs' RX/TX.
CONTROL_UART_PINS = (Pin.parse("PB2"), Pin.parse("PB3"), Pin.parse("PD0"), Pin.parse("PD1"))

# --- communication board (LEDs active low: cleared bit = LED on) ---------------
LED_POS = _pins("PA6", "PE1", "PC6", "PC3", "PC1", "PD6")
LED_NEG = _pins("PA5", "PE0", "PC7", "PC4", "PC0", "PD5")
LED_JOINT = _pins("PD7", "PA7", "PE2", "PC5", "PC2", "PD4")

#: IR multiplexer selector bits: channel number = A + 2B + 4C.
IR_SEL_A, IR_SEL_B, IR_SEL_C = Pin.parse("PA2"), Pin.parse("PA1"), Pin.parse("PA0")
IR_SEL_MASK = IR_SEL_A.mask | IR_SEL_B.mask | IR_SEL_C.mask

#: Optical switches (inputs, active low against the internal pull-up: a neighbour on body
#: side 1..6 pulls its pin to ground; an unwired input reads "no neighbour"). The thesis names
#: no pins for them (§4.3.4 only says they exist); these are free pins of the comm board, our
#: choice for the v2 firmware, clear of the ISP lines MOSI/MISO/SCK (PB5..PB7) so a switch
#: never fights the programmer (docs/firmware.md, "Pins we chose").
OPTICAL_SWITCH = _pins("PB0", "PB1", "PB4", "PA3", "PA4", "PD2")
OPTICAL_SWITCH_ACTIVE_LOW = True


def dip_levels(ident: int) -> int:
    """PINC as the control board reads it when its DIP switches are set to ``ident``."""
    return (~ident if DIP_ACTIVE_LOW else ident) & 0xFF


def dip_id(levels: int) -> int:
    """The id the DIP switches give for the levels ``levels`` on their port."""
    return dip_levels(levels)  # the complement is its own inverse


def switch_levels(present: list[bool]) -> dict[str, int]:
    """Levels on the optical-switch pins, per port, for neighbours ``present`` on sides
    1..6 (only the switch pins' bits are meaningful)."""
    levels: dict[str, int] = {}
    for side, pin in OPTICAL_SWITCH.items():
        high = not present[side - 1] if OPTICAL_SWITCH_ACTIVE_LOW else present[side - 1]
        levels[pin.port] = levels.get(pin.port, 0) | (pin.mask if high else 0)
    return levels


#: Inputs each image pulls up (PORTx bits of input pins): the control board's DIP switches,
#: the comm board's optical switches. Everything else that is not an output stays floating.
CONTROL_PULLUPS = tuple(Pin(DIP_PORT, b) for b in range(8))
COMM_PULLUPS = tuple(OPTICAL_SWITCH.values())


def port_masks(pin_list: tuple[Pin, ...] | list[Pin]) -> dict[str, int]:
    """The bits of ``pin_list`` per port, every port named (0 where none)."""
    masks = dict.fromkeys(PORTS, 0)
    for p in pin_list:
        masks[p.port] |= p.mask
    return masks


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

"""The coil on-time limit on the chip: the flashed control image, in simavr, switches a magnet
off on the tick its limit names and says LIM on its debug UART, as the model does."""

from __future__ import annotations

from bus.codec import Kind, Link, encode_command
from bus.framer import Framer
from bus.timing import MAGNET_ON_LIMIT_TICKS, NS_PER_S, TICK_NS
from hexbench.firmware import TOLERANCE_NS, differential
from toolchain import needs_avr

pytestmark = needs_avr

S3_POS = 0x40  # PB6 (bus.pins.MAGNET_POS[3])


def _debug_frames(events):
    framer = Framer(Link.DEBUG)
    return [t.frame for e in events if e.what == "debug"
            for t in framer.feed(int(e.detail.split()[0], 16), e.t_ns)]


def _on_off(events):
    """When PB6 of the control board went high, and low again after that."""
    b = [(e.t_ns, int(e.detail.split()[2], 16)) for e in events
         if e.what == "port" and e.detail.startswith("control B") and e.t_ns > 10 * NS_PER_S]
    on = next(t for t, v in b if v & S3_POS)
    off = next(t for t, v in b if t > on and not v & S3_POS)
    return on, off


def test_a_magnet_left_on_is_switched_off_and_reported_in_simavr():
    seconds = 11 + MAGNET_ON_LIMIT_TICKS * TICK_NS / NS_PER_S + 2
    model, firmware = differential("v2", [(int(11 * NS_PER_S), encode_command("SxP", 3))], seconds)
    on, off = _on_off(firmware)
    assert abs((off - on) - MAGNET_ON_LIMIT_TICKS * TICK_NS) <= TICK_NS
    lims = [f for f in _debug_frames(firmware) if f.kind is Kind.COIL_LIMIT]
    assert [f.raw[3:6] for f in lims] == [bytes([0, 0b100, 0])]
    acts = [f for f in _debug_frames(firmware) if f.kind is Kind.ACTUATORS]
    assert acts[-1].view["magnets"] == [0] * 6  # the report follows the switch-off
    m_on, m_off = _on_off(model)
    assert abs(off - m_off) <= TOLERANCE_NS and abs(on - m_on) <= TOLERANCE_NS

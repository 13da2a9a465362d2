"""The coil on-time limit on the chip: the flashed control image, in simavr, switches a coil
off on the tick its limit names and says LIM on its debug UART, as the model does: a magnet's
positive relay and its negative relay (8 s), and a solenoid (60 s)."""

from __future__ import annotations

import pytest

from bus.codec import Kind, Link, encode_command
from bus.framer import Framer
from bus.pins import JOINT, MAGNET_NEG, MAGNET_POS, Pin
from bus.timing import MAGNET_ON_LIMIT_TICKS, NS_PER_S, SOLENOID_ON_LIMIT_TICKS, TICK_NS
from hexbench.firmware import TOLERANCE_NS, differential
from toolchain import needs_avr

pytestmark = needs_avr

SENT_S = 11  # after the boot


def _debug_frames(events):
    framer = Framer(Link.DEBUG)
    return [t.frame for e in events if e.what == "debug"
            for t in framer.feed(int(e.detail.split()[0], 16), e.t_ns)]


def _on_off(events, pin: Pin) -> tuple[int, int]:
    """When the control board's ``pin`` went high, and low again after that."""
    writes = [(e.t_ns, int(e.detail.split()[2], 16)) for e in events
              if e.what == "port" and e.detail.startswith(f"control {pin.port}")
              and e.t_ns > SENT_S * NS_PER_S - TICK_NS]
    on = next(t for t, v in writes if v & pin.mask)
    off = next(t for t, v in writes if t > on and not v & pin.mask)
    return on, off


@pytest.mark.parametrize("function,index,pin,limit,lim", [
    ("SxP", 3, MAGNET_POS[3], MAGNET_ON_LIMIT_TICKS, (0, 0b100, 0)),  # PB6
    ("SxN", 2, MAGNET_NEG[2], MAGNET_ON_LIMIT_TICKS, (0, 0, 0b10)),  # PD5
    ("JxOpen", 2, JOINT[2], SOLENOID_ON_LIMIT_TICKS, (0b10, 0, 0)),  # PA3
], ids=["magnet-positive", "magnet-negative", "solenoid"])
def test_a_coil_left_on_is_switched_off_and_reported_in_simavr(function, index, pin, limit, lim):
    seconds = SENT_S + limit * TICK_NS / NS_PER_S + 2
    model, firmware = differential("v2", [(SENT_S * NS_PER_S, encode_command(function, index))], seconds)
    on, off = _on_off(firmware, pin)
    assert abs((off - on) - limit * TICK_NS) <= TICK_NS
    lims = [f for f in _debug_frames(firmware) if f.kind is Kind.COIL_LIMIT]
    assert [f.raw[3:6] for f in lims] == [bytes(lim)]
    acts = [f for f in _debug_frames(firmware) if f.kind is Kind.ACTUATORS]
    assert acts[-1].view["magnets"] == [0] * 6 and acts[-1].view["joints_open"] == [False] * 6
    m_on, m_off = _on_off(model, pin)
    assert abs(off - m_off) <= TOLERANCE_NS and abs(on - m_on) <= TOLERANCE_NS

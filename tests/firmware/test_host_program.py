"""The C firmware as a virtual module's program (module_sim.firmware): the same bytes at the
same sim times as the Python programs, one library for any number of boards."""

from __future__ import annotations


import pytest

from bus.codec import encode_command
from bus.timing import NS_PER_S
from toolchain import needs_avr

pytestmark = needs_avr


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_host_firmware_equals_the_model_exactly(profile):
    """Every byte, port change, drop and overrun at the same nanosecond (no tolerance)."""
    from hexbench.firmware import compare, default_script
    from module_sim.script import run_script

    script = default_script(profile)
    end = max(t for t, _ in script) / NS_PER_S + 5
    model = run_script(script, end, profile=profile)
    firmware = run_script(script, end, profile=profile, program="firmware")
    assert len(firmware) > 2000
    assert compare(model, firmware, tolerance_ns=0) == []


def test_every_board_keeps_its_own_memory():
    """Three modules on one library: each answers Report with its own id (the DIP switches
    its control board sent after the handshake) and its own LEDs."""
    from bus.clock import VirtualClock
    from bus.session import SessionOptions
    from bus.transport import Bus
    from module_sim.module import VirtualModule
    from module_sim.profiles import V2

    bus = Bus(VirtualClock(), "host-firmware", options=SessionOptions(isolated=True))
    try:
        mods = [VirtualModule(bus, ident, V2, program="firmware") for ident in (3, 7, 200)]
        sent = []
        for m in mods:
            m.comm.uart1.on_tx = lambda data, starts, m=m: sent.append((m.id, bytes(data)))
            m.power_up()
        bus.clock.run(until_ns=10 * NS_PER_S)
        # Select the middle one alone, then light its LEDs: only its ports change
        for byte_ns, frame in enumerate((encode_command("Select", 1, 7, 0), encode_command("LOn"),
                                         encode_command("Report"))):
            for k, b in enumerate(frame):
                t = (11 + 2 * byte_ns) * NS_PER_S + (k + 1) * 33_333_333
                for m in mods:
                    bus.clock.call_at(t, m._ir_rx, 0, b, t - 33_333_333, False)
        bus.clock.run(until_ns=20 * NS_PER_S)
        pos = [(ident, data) for ident, data in sent if b"POS" in data]
        assert [(i, d[-10:]) for i, d in pos] == [(7, b"POS" + bytes([7, 128, 128, 0, 2]) + b"\n\r")]
        lit = {m.id: m.comm.port["C"] for m in mods}
        assert lit[7] != lit[3] == lit[200]  # LOn cleared the LED bits of m7 only
    finally:
        bus.close()


def test_compare_model_from_the_command_line(tmp_path, capsys):
    from hexbench.cli import main

    out = tmp_path / "fw.mcap"
    assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual", "--program",
                 "firmware", "--compare-model", "--record", str(out)]) == 0
    said = capsys.readouterr().out
    assert "compare: firmware and model agree on all" in said
    # no --program compares the default (the firmware); the model against itself is refused
    assert main(["run", "pair", "--compare-model", "--program", "model"]) == 2
    assert "give --program firmware --clock virtual" in capsys.readouterr().err


def test_first_divergence_names_the_frame():
    from bus.codec import Link, parse
    from bus.envelope import Envelope
    from hexbench.compare import first_divergence

    def env(raw: bytes, t: int) -> Envelope:
        return Envelope.of(parse(Link.CENTRE, raw), src="m1.comm", dst="pc", sim_time_ns=t,
                           wall_time_ns=0, seq=t)

    a = [env(b"\n\r\n\rM: ACK\x01\n\r", 10), env(b"\n\r\n\rM: ACK\x02\n\r", 20)]
    assert first_divergence(a, list(a)) == (2, None)
    n, d = first_divergence(a, [a[0], env(b"\n\r\n\rM: ACK\x03\n\r", 20)])
    assert (n, d.index) == (2, 1) and d.got.raw.endswith(b"\x03\n\r")
    n, d = first_divergence(a, a[:1])
    assert d.index == 1 and d.got is None

"""What keeps a real board safe and reachable, in both programs (the Python model and the C
firmware built for the host): every DIP id is an address, no coil stays on past its limit,
and the v2 self-test and version report (docs/protocol.md)."""

from __future__ import annotations

import pytest

from bus import codec
from bus.codec import Kind, Link
from bus.framer import Framer
from bus.timing import MAGNET_ON_LIMIT_TICKS, NS_PER_S, SELFTEST_PULSE_TICKS, SOLENOID_ON_LIMIT_TICKS, TICK_NS
from module_sim.script import run_script

VERSION = "%d.%d" % codec.FIRMWARE_VERSION

PROGRAMS = ["model", "firmware"]
BOOTED_NS = 10 * NS_PER_S  # both boards listen by then


def _cmd(t_s: float, name: str, *args: int) -> tuple[int, bytes]:
    return int(t_s * NS_PER_S), codec.encode_command(name, *args)


def _frames(events, stream: str, link: Link) -> list[tuple[int, codec.Frame]]:
    """The frames of one output stream (``ir`` or ``debug``), each with its first byte's time."""
    framer = Framer(link)
    out: list[tuple[int, codec.Frame]] = []
    for e in events:
        if e.what == stream:
            out += [(t.t_first_ns, t.frame) for t in framer.feed(int(e.detail.split()[0], 16), e.t_ns)]
    return out


def _kinds(frames, kind: Kind) -> list[tuple[int, codec.Frame]]:
    return [(t, f) for t, f in frames if f.kind is kind]


@pytest.mark.parametrize("program", PROGRAMS)
def test_every_dip_id_from_1_to_255_is_an_address(program):
    """The id '~' (126) is the timed receive's timeout value: v2 tells a timeout apart from a
    received byte, so module 126 answers like any other."""
    for ident in range(1, 256):
        script = [_cmd(10, "Select", 1, ident, 0), _cmd(11.5, "Report")]
        frames = _frames(run_script(script, 13.5, module_id=ident, program=program), "ir", Link.CENTRE)
        acks = [f.view["byte"] for _, f in _kinds(frames, Kind.ACK)]
        pos = [f.view["id"] for _, f in _kinds(frames, Kind.POSITION)]
        assert acks == [60, 61] and pos == [ident], f"m{ident} ({program}): ACKs {acks}, POS {pos}"


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_a_coil_left_on_is_switched_off_at_its_limit_and_reported(profile):
    """A solenoid left open (JxOpen, never closed) and a magnet left on (SxP): each goes off on
    the tick its limit names, with a LIM line; both programs alike, to the byte and the ns."""
    script = [_cmd(10, "JxOpen", 2), _cmd(12, "SxP", 3)]
    seconds = 12 + (SOLENOID_ON_LIMIT_TICKS + 300) * TICK_NS / NS_PER_S
    runs = {p: run_script(script, seconds, profile=profile, program=p) for p in PROGRAMS}
    debug = {p: _frames(ev, "debug", Link.DEBUG) for p, ev in runs.items()}
    assert [(t, f.raw) for t, f in debug["model"]] == [(t, f.raw) for t, f in debug["firmware"]]
    lims = _kinds(debug["model"], Kind.COIL_LIMIT)
    assert [f.raw[3:6] for _, f in lims] == [bytes([0, 0b100, 0]), bytes([0b10, 0, 0])]
    assert lims[0][1].view["magnets"][2] == 1 and lims[1][1].view["joints_open"][1]
    # the ports: J2 (PA3) on at ~10.7 s, off a minute later; S3+ (PB6) on for 8 s
    ports = [(e.t_ns, e.detail) for e in runs["model"]
             if e.what == "port" and e.detail.startswith("control") and e.t_ns > BOOTED_NS]
    j_on = next(t for t, d in ports if d.startswith("control A") and int(d.split()[2], 16) & 0x08)
    j_off = next(t for t, d in ports if t > j_on and d.startswith("control A") and not int(d.split()[2], 16) & 0x08)
    s_on = next(t for t, d in ports if d.startswith("control B") and int(d.split()[2], 16) & 0x40)
    s_off = next(t for t, d in ports if t > s_on and d.startswith("control B") and not int(d.split()[2], 16) & 0x40)
    assert abs((j_off - j_on) - SOLENOID_ON_LIMIT_TICKS * TICK_NS) <= TICK_NS
    assert abs((s_off - s_on) - MAGNET_ON_LIMIT_TICKS * TICK_NS) <= TICK_NS
    assert lims[0][0] == s_off and lims[1][0] == j_off  # reported the instant it went off
    if profile == "v2":  # and the actuator report follows the limit's switch-off
        acts = _kinds(debug["model"], Kind.ACTUATORS)
        assert acts[-1][1].view["joints_open"] == [False] * 6 and acts[-1][1].view["magnets"] == [0] * 6


def test_a_coil_switched_off_in_time_is_not_limited():
    """The limit counts from the last time the coil came on: a magnet pulsed for 6 s, off,
    then 6 s again never meets its 8 s limit."""
    script = [_cmd(10, "SxP", 1), _cmd(16, "SxOff", 1), _cmd(17, "SxP", 1), _cmd(23, "SxOffAll")]
    for program in PROGRAMS:
        frames = _frames(run_script(script, 30, program=program), "debug", Link.DEBUG)
        assert not _kinds(frames, Kind.COIL_LIMIT), program


@pytest.mark.parametrize("program", PROGRAMS)
def test_the_self_test_pulses_every_coil_and_reports_the_dip_id_and_switches(program):
    switches = 0b100101
    events = run_script([_cmd(10, "SelfTest")], 16, module_id=77, switches=switches, program=program)
    debug = _frames(events, "debug", Link.DEBUG)
    acts = [f.view for _, f in _kinds(debug, Kind.ACTUATORS)]
    assert len(acts) == 36  # each of 18 coils on, then off
    on = acts[0::2]
    assert [v["joints_open"].index(True) for v in on[:6]] == list(range(6))
    assert [v["magnets"].index(1) for v in on[6:12]] == list(range(6))
    assert [v["magnets"].index(-1) for v in on[12:]] == list(range(6))
    assert all(v["joints_open"] == [False] * 6 and v["magnets"] == [0] * 6 for v in acts[1::2])
    (t, tst), = _kinds(debug, Kind.SELF_TEST)
    assert tst.view["id"] == 77 and tst.view["switches"] == [True, False, True, False, False, True]
    assert t - _kinds(debug, Kind.ACTUATORS)[0][0] >= 36 * SELFTEST_PULSE_TICKS * TICK_NS - TICK_NS
    assert [a.view["byte"] for _, a in _kinds(_frames(events, "ir", Link.CENTRE), Kind.ACK)] == [64]


@pytest.mark.parametrize("profile", ["v2", "thesis-2009"])
def test_version_names_the_v2_firmware_and_a_thesis_module_does_not_know_it(profile):
    for program in PROGRAMS:
        frames = _frames(run_script([_cmd(10, "Version")], 12, profile=profile, program=program),
                         "ir", Link.CENTRE)
        ver = [f.view for _, f in _kinds(frames, Kind.VERSION)]
        acks = [f.view["byte"] for _, f in _kinds(frames, Kind.ACK)]
        if profile == "v2":
            assert ver == [{"preamble": True, "role": "M", "version": VERSION, "profile": "v2"}] and acks == [63]
        else:
            assert ver == [] and acks == [ord("N")]

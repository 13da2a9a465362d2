"""The fleet core (module_sim.core) against the Python path it replaces: the same firmware, the
same medium, the same frames — checked on fleets whose banners pile up at the PC, with the PC
commanding them, and on what the PC itself decoded out of the pile-up."""

from __future__ import annotations

import json

import pytest

from bus.clock import VirtualClock, WallClock
from bus.envelope import Envelope
from bus.ir import Burst
from bus.scenario import loads
from bus.session import SessionOptions, open_session
from bus.timing import NS_PER_S
from bus.transport import Bus
from module_sim.fleet import Fleet
from planner_svc.endpoint import PcEndpoint
from tests.support.block_fleets import block_scenarios


_RX_LIGHT: list[list[bytes]] = []  # the PC's ir/rx samples of each run, newest last


def _run(scenario, core: bool, *, seed_commands: int = 4):
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, f"core{int(core)}", session=session)
    frames: list[tuple] = []
    events: list[bytes] = []
    pc_light: list[bytes] = []
    records: list[tuple[str, bytes]] = []  # actuator/LED/multiplexer records: key and payload
    bus.subscribe_frames(lambda e: frames.append((e.sim_time_ns, e.src, e.link, e.seq, e.channel,
                                                  e.first_byte_ns, e.raw)))
    bus.subscribe(bus.keys.event("world"), lambda k, p: events.append(p))
    bus.subscribe(bus.keys.ir_rx("pc"), lambda k, p: pc_light.append(p))
    bus.subscribe(bus.keys.actuators_all, lambda k, p: records.append((bus.keys.relative(k), p)))
    try:
        fleet = Fleet(bus, scenario, core=core)
        assert (fleet.core is not None) == core
        pc = PcEndpoint(bus)
        fleet.power_up()
        clock.run(until_ns=9 * NS_PER_S)
        for k in range(seed_commands):  # broadcast commands the whole fleet answers
            pc.send("SxP" if k % 2 == 0 else "SxOff", 1 + k % 6)
            clock.run(until_ns=clock.now_ns() + 1_500_000_000)
        received = [(r.frame.raw, r.t_first_ns, r.t_last_ns) for r in pc.received]
        _RX_LIGHT.append(pc_light)
        return sorted(frames), received, fleet.world.collisions, events, records
    finally:
        bus.close()
        session.close()


def _per_module(records: list[tuple[str, bytes]]) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for key, payload in records:
        out.setdefault(key, []).append(payload)
    return out


@pytest.mark.parametrize("n", [12, 60])
def test_the_core_gives_the_python_paths_frames_and_the_pcs_bytes(n):
    """Both boards of every module, UART0, the multiplexer and the IR medium (collisions at the
    PC included) in C give every frame the FirmwareDriver path gives, at the same times, and
    the PC decodes the same bytes out of the boot pile-up."""
    sc = block_scenarios(n, "firmware")[0]
    py_frames, py_rx, py_coll, py_events, py_records = _run(sc, core=False)
    c_frames, c_rx, c_coll, c_events, c_records = _run(sc, core=True)
    assert len(py_frames) > 20 * n
    assert c_frames == py_frames
    assert py_coll > 0 and c_coll == py_coll  # the pile-up is there, and the same
    assert c_rx == py_rx
    assert sorted(c_events) == sorted(py_events)  # collision events: receivers, sources, bytes
    # every actuator/LED/multiplexer record, byte for byte, in each module's order (the core
    # writes a window's records at its end: modules interleave differently, each module does not)
    assert len(py_records) > 4 * n
    assert _per_module(c_records) == _per_module(py_records)
    light = _RX_LIGHT[-1]  # the core writes the PC's bursts itself: each is Burst.to_json's bytes
    assert len(light) > n
    assert all(Burst.from_dict(json.loads(p)).to_json() == p for p in light)


def _rendered(kept: bool, monkeypatch) -> list[bytes]:
    """A 12-module core run's frame samples (boot and one command)."""
    import module_sim.core as core_module

    monkeypatch.setattr(core_module, "_PARTS_MAX", 1 << 16 if kept else 0)
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, f"render{int(kept)}", session=session)
    payloads: list[bytes] = []
    bus.subscribe(bus.keys.frames, lambda k, p: payloads.append(p))
    try:
        fleet = Fleet(bus, block_scenarios(12, "firmware")[0])
        assert fleet.core is not None
        pc = PcEndpoint(bus)
        fleet.power_up()
        clock.run(until_ns=9 * NS_PER_S)
        pc.send("SxP", 2)
        clock.run(until_ns=clock.now_ns() + 1_500_000_000)
    finally:
        bus.close()
        session.close()
    return payloads


def test_the_frames_the_core_renders_are_envelope_json(monkeypatch):
    """Every frame sample the core renders is Envelope.to_json's bytes, and with no frame's
    parts kept (each frame's own, freed once rendered: a run with more distinct frames than
    Python remembers) the same frames come out."""
    kept, once = _rendered(True, monkeypatch), _rendered(False, monkeypatch)
    assert len(kept) > 200
    assert all(Envelope.from_json(p).to_json() == p for p in kept + once)
    timeless = lambda p: p[:p.index(b',"wall_time_ns"')] + p[p.index(b',"seq"'):]  # noqa: E731
    assert list(map(timeless, kept)) == list(map(timeless, once))


def test_the_fleet_says_why_it_leaves_the_core():
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    bus = Bus(clock, "corewhy", session=session)
    try:
        sc = block_scenarios(3, "firmware")[0]
        assert Fleet.core_refusal(bus, sc) is None
        assert "mux-cut" in Fleet.core_refusal(bus, sc, mux_cut=True)
        assert "firmware program" in Fleet.core_refusal(bus, block_scenarios(3, "model")[0])
        mixed = loads('profile = "v2"\nprogram = "firmware"\nfixed = [0, 0]\n[[modules]]\ncell = [0, 0]\n'
                      'id = 1\n[[modules]]\ncell = [1, 0]\nid = 2\nprogram = "model"\n')
        assert "Python programs" in Fleet.core_refusal(bus, mixed)
        with_simavr = loads('profile = "v2"\nprogram = "firmware"\nfixed = [0, 0]\n[[modules]]\n'
                            'cell = [0, 0]\nid = 1\n[[modules]]\ncell = [1, 0]\nid = 2\nprogram = "simavr"\n')
        assert Fleet.core_refusal(bus, with_simavr) == "some virtual modules run the images in simavr"
        noisy = loads('profile = "v2"\nprogram = "firmware"\nfixed = [0, 0]\nbit_error_rate = 0.001\n'
                      '[[modules]]\ncell = [0, 0]\nid = 1\n')
        assert "bit errors" in Fleet.core_refusal(bus, noisy)
        wall = Bus(WallClock(), "corewall", session=session)
        assert "virtual clock" in Fleet.core_refusal(wall, sc)
        wall.close()
    finally:
        bus.close()
        session.close()


def test_a_scenario_that_names_no_program_runs_the_firmware_on_the_core():
    """The fast path is the default: no ``program`` in the scenario means the C firmware on the
    fleet core; where the run cannot have it, the Python programs and one line saying why."""
    clock = VirtualClock()
    session = open_session(SessionOptions(isolated=True))
    buses = []

    def bus(clock, name):
        buses.append(Bus(clock, name, session=session))
        return buses[-1]

    plain = 'fixed = [0, 0]\n[[modules]]\ncell = [0, 0]\nid = 1\n[[modules]]\ncell = [1, 0]\nid = 2\n'
    try:
        assert loads(plain).program is None
        fleet = Fleet(bus(clock, "coredefault"), loads(plain))
        assert fleet.core is not None and fleet.program_note is None
        assert {m.program for m in fleet.modules.values()} == {"firmware"}
        cases = [(VirtualClock(), "bit_error_rate = 0.001\n" + plain, {}, "bit errors"),
                 (VirtualClock(), "ir_baud = 2400\n" + plain, {}, "300 baud"),
                 (VirtualClock(), plain, {"mux_cut": True}, "mux-cut"),
                 (VirtualClock(), plain, {"core": False}, "Python path"),
                 (WallClock(), plain, {}, "a wall clock"),
                 (VirtualClock(), plain.replace("id = 2\n", 'id = 2\nprogram = "simavr"\n'), {}, "simavr")]
        for i, (c, text, kw, why) in enumerate(cases):
            fleet = Fleet(bus(c, f"coremodel{i}"), loads(text), **kw)
            assert fleet.core is None
            assert fleet.program_note.startswith("program: the Python programs") and why in fleet.program_note
            assert "\n" not in fleet.program_note
            assert fleet.scenario.program == "model"
        named = Fleet(bus(VirtualClock(), "corenamed"), loads('program = "model"\n' + plain))
        assert named.core is None and named.program_note is None  # a scenario that says is obeyed
    finally:
        for b in buses:
            b.close()
        session.close()

"""Bus replay (``hexbench replay --to-bus``) and replay-and-compare (``--compare``) against
recordings of a virtual ``pair`` fleet driven by the PC endpoint."""

from __future__ import annotations

import dataclasses

import pytest

from hexbench.cli import main
from bus.clock import WallClock
from bus.session import SessionOptions
from bus.transport import Bus
from bus.envelope import Envelope
from hexbench.bus_replay import BusReplay
from hexbench.compare import compare, describe_frame
from edit import change_frame
from recordings.reader import iter_samples, read_frames
from hexbench.virtual_run import VirtualRun


def _ident(e: Envelope) -> tuple:
    return (e.link, e.src, e.dst, e.channel, e.sim_time_ns, e.first_byte_ns, e.raw)


def test_the_recording_holds_the_commands_and_their_acks(pair_recording, pair_commands):
    frames = list(read_frames(pair_recording))
    pc = [e for e in frames if e.link == "pc"]
    acks = [e for e in frames if e.link == "centre" and e.kind == "ack"]
    assert len(pc) == len(acks) == len(pair_commands)
    assert all(e.origin == "virtual" for e in frames)


def test_replay_into_a_fresh_fleet_travels_as_ir_light(pair_recording, tmp_path):
    """PC frames go through the PC endpoint (IR bursts on ir/tx/pc), marked as a replay, at the
    recorded times; the fresh fleet answers them exactly as in the recording."""
    original = list(read_frames(pair_recording))
    out = tmp_path / "replayed.mcap"
    with VirtualRun("pair", record=out) as run:
        replay = BusReplay.from_recording(run.bus, pair_recording, links=["pc"], pcs=run.pcs)
        replay.schedule()
        run.clock.run(until=lambda: replay.done, timeout_s=60)
        run.clock.run(until_ns=original[-1].sim_time_ns)
    again = list(read_frames(out))
    sent = [e for e in again if e.link == "pc"]
    assert [_ident(e) for e in sent] == [_ident(e) for e in original if e.link == "pc"]
    assert {e.origin for e in sent} == {"replay"}
    bursts = [s.json() for s in iter_samples(out, ["ir/tx/pc"])]
    assert b"".join(bytes.fromhex(b["data"]) for b in bursts) == b"".join(e.raw for e in sent)
    answers = [_ident(e) for e in again if e.link != "pc"]
    assert answers == [_ident(e) for e in original if e.link != "pc"]


def test_wall_clock_replay_keeps_order_and_scales_time(pair_recording):
    """Non-PC links are republished as envelopes; at --speed 50 the gaps shrink 50 times."""
    recorded = [e for e in read_frames(pair_recording) if e.link == "debug"]
    clock = WallClock()
    bus = Bus(clock, "wallreplay", options=SessionOptions(isolated=True))
    got: list[Envelope] = []
    try:
        bus.subscribe_frames(got.append, "debug")
        replay = BusReplay.from_recording(bus, pair_recording, links=["debug"], speed=50)
        replay.schedule()
        clock.run(until=lambda: replay.done and len(got) == len(recorded), timeout_s=30)
    finally:
        bus.close()
    assert [(e.src, e.dst, e.raw) for e in got] == [(e.src, e.dst, e.raw) for e in recorded]
    assert {e.origin for e in got} == {"replay"}
    span_recorded = recorded[-1].first_byte_ns - recorded[0].first_byte_ns
    span_replayed = got[-1].first_byte_ns - got[0].first_byte_ns
    # wall-clock scheduling: a loaded machine publishes late by a few ms (not a speed test)
    assert span_replayed == pytest.approx(span_recorded / 50, rel=0.15)


def test_compare_against_the_same_scenario_finds_no_divergence(pair_recording, pair_commands, capsys):
    result = compare(pair_recording)
    assert result.ok and result.replayed == len(pair_commands)
    assert result.matched == result.expected > 50
    assert main(["replay", str(pair_recording), "--to-bus", "--compare"]) == 0
    out = capsys.readouterr().out
    assert f"no divergence: all {result.expected} recorded frames reproduced, byte for byte" in out


def _bump_ack_byte(e: Envelope) -> Envelope:
    raw = bytearray(e.raw)
    i = raw.index(b"ACK") + 3
    raw[i] += 1
    return dataclasses.replace(e, raw=bytes(raw), view={**e.view, "byte": raw[i]})


def test_compare_names_exactly_the_changed_ack(pair_recording, tmp_path, capsys):
    """A copy of the recording with one ACK byte changed (SxP's 11 -> 12): the fresh fleet
    still says 11, and the report is about exactly that frame."""
    edited = tmp_path / "one-ack-changed.mcap"
    sxp_ack = lambda e: e.link == "centre" and e.kind == "ack" and e.view.get("byte") == 11  # noqa: E731
    changed = change_frame(pair_recording, edited, sxp_ack, _bump_ack_byte)
    original = next(e for e in read_frames(pair_recording) if sxp_ack(e))
    compared = [e for e in read_frames(edited) if e.link != "pc"]
    index = next(i for i, e in enumerate(compared) if e.raw == changed.raw)

    assert main(["replay", str(edited), "--to-bus", "--compare"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert lines[1:] == [
        f"first divergence at compared frame {index + 1} of {len(compared)}: link centre, source m2.comm, "
        f"sim time {original.sim_time_ns} ns",
        f"  expected: {describe_frame(changed)}",
        f"  got:      {describe_frame(original)}",
    ]
    assert "0a0d0a0d4d3a2041434b0c0a0d" in lines[2] and "0a0d0a0d4d3a2041434b0b0a0d" in lines[3]
    d = compare(edited).divergence
    assert d is not None and d.index == index
    assert _ident(d.expected) == _ident(changed) and _ident(d.got) == _ident(original)


def test_compare_reports_a_run_that_stops_short(pair_recording, tmp_path):
    """Frames the fresh run never makes: here the recording's last command is not replayed."""
    last_pc = [e for e in read_frames(pair_recording) if e.link == "pc"][-1]
    trimmed = tmp_path / "no-last-command.mcap"
    from edit import rewrite
    rewrite(pair_recording, trimmed,
            lambda s: None if s.topic == "frame/pc/pc" and Envelope.from_json(s.data).seq == last_pc.seq else s.data)
    result = compare(trimmed)
    assert not result.ok and result.divergence.got is None
    assert result.divergence.expected.sim_time_ns > last_pc.first_byte_ns


@pytest.mark.parametrize("argv, message", [
    (["--compare", "--speed", "2"], "--speed does not apply"),
    (["--to-bus", "--links", "pc,bogus"], "unknown link(s) bogus"),
    (["--to-bus", "--speed", "0"], "--speed must be positive"),
    (["--to-bus", "--scenario", "pair"], "--scenario only goes with --compare"),
])
def test_bus_replay_usage_errors(pair_recording, capsys, argv, message):
    assert main(["replay", str(pair_recording), *argv]) == 2
    assert message in capsys.readouterr().err


def test_compare_needs_a_scenario_it_can_rebuild(recorded, capsys):
    assert main(["replay", str(recorded.path), "--compare"]) == 2
    assert "cannot rebuild the run" in capsys.readouterr().err

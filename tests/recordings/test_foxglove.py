"""Foxglove-ready recordings: a ``foxglove.SceneUpdate`` scene and a ``foxglove.Log`` of frames
beside the bus's channels, read back with the ``mcap`` reader and Foxglove's protobuf decoder
(``mcap-protobuf-support``), a schema on every channel, real dates as log times."""

from __future__ import annotations

import re
import subprocess
from collections import defaultdict

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from hexbench.cli import main
from recordings.foxglove import module_cells
from recordings.reader import iter_samples, read_metadata

START = "2026-11-25T08:00:00Z"
START_NS = 1_795_593_600 * 10**9


@pytest.fixture(scope="module")
def planned_run(tmp_path_factory: pytest.TempPathFactory):
    out = tmp_path_factory.mktemp("fox") / "pair.mcap"
    assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual", "--record", str(out),
                 "--start-time", START]) == 0
    return out


def _decoded(path, topic):
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(m.log_time, dec) for _, _, m, dec in reader.iter_decoded_messages(topics=[topic])]


def test_the_last_scene_puts_every_module_at_its_goal(planned_run, capsys):
    scenes = _decoded(planned_run, "foxglove/scene")
    assert len(scenes) > 3
    t_last, last = scenes[-1]
    cells = dict(module_cells(last))
    assert cells == {"m1": (0, 0), "m2": (0, 1)}  # the pair scenario's goal
    goal = next(e for e in last.entities if e.id == "goal")
    assert len(goal.lines) == 2 and all(len(loop.points) == 6 for loop in goal.lines)
    module = next(e for e in last.entities if e.id == "m1")
    assert module.frame_id == "lattice" and len(module.triangles[0].points) == 6 * 9  # a hexagonal prism
    assert len(module.spheres) == 6 and len(module.lines[1].points) == 12  # joints, magnet bars
    assert "fixed" in module.texts[0].text
    # the scene moved on the way: m2 started at (1, 0), and was highlighted while it moved
    firsts = defaultdict(list)
    for _, s in scenes:
        for e in s.entities:
            firsts[e.id].append(e)
    assert dict(module_cells(scenes[0][1])).get("m2", (1, 0)) == (1, 0)
    assert any("moving" in e.texts[0].text for e in firsts["m2"])
    assert t_last == max(t for t, _ in scenes)


def test_frames_are_a_foxglove_log(planned_run):
    lines = _decoded(planned_run, "foxglove/log")
    with open(planned_run, "rb") as f:
        frames = sum(1 for _, ch, _ in make_reader(f).iter_messages(log_time_order=False)
                     if ch.topic.startswith("frame/"))
    assert len(lines) == frames > 20
    texts = [dec.message for _, dec in lines]
    assert any(t.startswith("pc → *  command Select mode=1") for t in texts)  # decoded, as the replay shows them
    assert any(" → pc  ack " in t and "meaning='Select'" in t for t in texts)
    t, first = lines[0]
    assert first.timestamp.seconds * 10**9 + first.timestamp.nanos == t  # the message's time is its log time


def test_every_channel_has_a_schema_and_log_times_are_dates(planned_run, rerun_bin):
    with open(planned_run, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {ch.topic: summary.schemas.get(ch.schema_id) for ch in summary.channels.values()}
    assert all(s is not None for s in schemas.values()), [t for t, s in schemas.items() if s is None]
    assert schemas["foxglove/scene"].name == "foxglove.SceneUpdate" and schemas["foxglove/scene"].encoding == "protobuf"
    assert schemas["foxglove/log"].name == "foxglove.Log"
    assert {schemas[t].name for t in schemas if t.startswith("ir/")} == {"hexbot.IrLight"}
    assert schemas["world/sync"].name == "hexbot.Sync"
    meta = read_metadata(planned_run)
    assert meta["start_time_ns"] == START_NS and meta["start_time"] == "2026-11-25T08:00:00.000Z"
    stats = summary.statistics
    assert START_NS <= stats.message_start_time and stats.message_end_time < START_NS + 60 * 10**9
    res = subprocess.run([rerun_bin, "mcap", "check", str(planned_run)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr


def test_replay_and_info_still_read_sim_time(planned_run, tmp_path, capsys):
    """The start instant is subtracted again where sim time is shown."""
    from recordings.player import Player
    player = Player(planned_run)
    assert player.t0_ns == START_NS and 40e9 < player.duration_ns < 60e9  # ~45 s, not 56 years
    first_sample_ns = min(s.log_time_ns for s in iter_samples(planned_run))
    assert first_sample_ns == START_NS  # the run's first sample at sim time 0
    assert main(["info", str(planned_run)]) == 0
    duration = re.search(r"^duration: +(\S+) s", capsys.readouterr().out, re.M).group(1)
    assert duration == f"{player.duration_ns / 1e9:.3f}"


def test_a_bad_start_time_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "pair", "--clock", "virtual", "--record", str(tmp_path / "x.mcap"), "--start-time", "noon"])
    assert exc.value.code == 2 and "--start-time" in capsys.readouterr().err


@settings(max_examples=300, deadline=None)
@given(t=st.integers(min_value=0, max_value=2**32 * 10**9 - 1), noise=st.booleans())
def test_the_fast_frame_log_is_the_sdks_own_encoding(t, noise):
    """The recorder encodes a line once and the timestamp per frame: byte for byte what the SDK
    writes for the whole message."""
    from bus.envelope import Envelope
    from recordings.foxglove import FrameLog
    payload = (b'{"link":"side","src":"m1.comm","dst":"side1","raw":"ff","sim_time_ns":3164788676,'
               b'"wall_time_ns":1795567395901649287,"seq":7,"kind":"' + (b'noise' if noise else b'probe')
               + b'","view":{"byte":255}}')
    log = FrameLog()
    for kind in (None, "noise" if noise else "probe"):  # found in the bytes, or given by the recorder
        assert log.log_payload(payload, kind, t) == log.log(Envelope.from_json(payload), t)


def test_a_recorder_joining_late_gets_the_whole_scene_with_sync(tmp_path):
    """``hexbench record --sync`` joins a running fleet and asks its world to republish the
    poses: the recording's scene holds every module although none moved while it recorded."""
    import signal

    from processes import free_port, hexbench, wall_fleet
    port = free_port()
    fleet = wall_fleet("pair", port, f"late{port}", seconds=30)
    out = tmp_path / "late.mcap"
    try:
        rec = hexbench("record", "--sync", "--seconds", "3", "--connect", f"tcp/127.0.0.1:{port}",
                       "--fleet", f"late{port}", "--out", str(out))
        text = rec.communicate(timeout=60)[0]
        assert rec.returncode == 0, text
    finally:
        fleet.send_signal(signal.SIGTERM)
        fleet.communicate(timeout=30)
    scenes = _decoded(out, "foxglove/scene")
    assert dict(module_cells(scenes[-1][1])) == {"m1": (0, 0), "m2": (1, 0)}


@settings(max_examples=200, deadline=None)
@given(t=st.integers(min_value=0, max_value=2**32 * 10**9 - 1), cell=st.tuples(st.integers(-9, 9), st.integers(-9, 9)),
       orientation=st.integers(0, 5), fixed=st.booleans(), real=st.booleans(), moving=st.booleans(),
       magnets=st.lists(st.sampled_from([-1, 0, 1, 2]), min_size=6, max_size=6),
       joints=st.lists(st.booleans(), min_size=6, max_size=6), name=st.sampled_from(["m1", "m42", "m250", "x"]))
def test_a_cached_scene_update_is_the_sdks_own_encoding(t, cell, orientation, fixed, real, moving, magnets, joints,
                                                       name):
    """A module's update is its entity's encoding but the timestamp, made once per look, behind
    the timestamp of the moment: byte for byte what the SDK writes for the whole update."""
    from bus.lattice import Cell
    from bus.messages import Actuators
    from foxglove.messages import SceneUpdate
    from recordings.foxglove import SceneView
    from recordings.scene import rest

    scene = SceneView()
    m = scene._module(name)
    m.placement, m.fixed, m.real, m.moving = rest(Cell(*cell), orientation), fixed, real, moving
    m.actuators = Actuators(name, 0, joints, magnets, [False] * 6, [False] * 6, [False] * 6, None)
    for at in (t, t // 2):  # the second from the cache
        assert scene._one(m, at) == SceneUpdate(entities=[scene._entity(m, at)]).encode()

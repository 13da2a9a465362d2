"""The recorder against a synthetic run: the file opens everywhere, nothing is lost."""

from __future__ import annotations

import json
import subprocess
from collections import Counter

from mcap.reader import make_reader

from recordings.reader import iter_records, read_frames, read_metadata, summary
from recordings.reader import Undecodable
from recordings.schemas import RECORDER_ERROR_TOPIC


def _frame_key(e):
    """Everything of an envelope but the wall time (which differs from run to run)."""
    return (e.link, e.src, e.dst, e.raw, e.sim_time_ns, e.seq, e.kind, e.first_byte_ns, e.channel)


def test_mcap_reader_reads_the_file(recorded):
    with open(recorded.path, "rb") as f:
        reader = make_reader(f)
        encodings = Counter(ch.message_encoding for _, ch, _ in reader.iter_messages(log_time_order=False))
        stats = reader.get_summary().statistics
        names = [m.name for m in reader.iter_metadata()]
    assert sum(encodings.values()) == stats.message_count
    assert encodings["json"] == recorded.tally.messages  # every bus sample; the rest is for Foxglove
    assert encodings["protobuf"] >= recorded.tally.frames  # a foxglove.Log line per frame, and the scene
    assert stats.chunk_count >= 1
    assert "hexbench" in names and "hexbench.stats" in names


def test_every_channel_has_a_schema(recorded):
    with open(recorded.path, "rb") as f:
        summ = make_reader(f).get_summary()
    kinds = set()
    for ch in summ.channels.values():
        schema = summ.schemas[ch.schema_id]  # no schemaless channel (id 0)
        kinds.add((ch.message_encoding, schema.encoding))
        if ch.message_encoding == "json":
            assert schema.encoding == "jsonschema" and isinstance(json.loads(schema.data), dict)
            if ch.topic.startswith(("frame/", "world/pose", "world/actuators", "planner/", "meta", "event/")):
                assert json.loads(schema.data)["type"] == "object"
        else:
            assert ch.topic.startswith("foxglove/") and schema.name.startswith("foxglove.")
    assert kinds == {("json", "jsonschema"), ("protobuf", "protobuf")}


def test_rerun_mcap_check_accepts_the_file(recorded, rerun_bin):
    out = subprocess.run([rerun_bin, "mcap", "check", str(recorded.path)], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr


def test_frames_per_link_equal_what_was_published(recorded):
    expected = recorded.published.frames_by_link()
    assert dict(recorded.tally.frames_by_link) == expected  # counted by the recorder as written
    assert dict(summary(recorded.path).tally.frames_by_link) == expected  # counted from the file


def test_every_raw_byte_is_present(recorded):
    got = [_frame_key(e) for e in read_frames(recorded.path)]
    assert got == [_frame_key(e) for e in recorded.published.frames]
    assert b"".join(e.raw for e in read_frames(recorded.path)) == b"".join(
        e.raw for e in recorded.published.frames)


def test_records_come_back_typed(recorded):
    want = [(t, r.to_dict() if hasattr(r, "to_dict") else r) for t, r in recorded.published.records]
    got = []
    for s, v in iter_records(recorded.path):
        if s.topic.startswith(("world/", "planner/", "meta")):
            assert not isinstance(v, Undecodable)
            got.append((s.topic, v.to_dict()))
        elif s.topic.startswith("event/"):
            got.append((s.topic, {"kind": v["kind"]}))
    assert got == want


def test_malformed_samples_are_recorded_as_errors(recorded):
    errors = [s.json() for s in summary_samples(recorded.path, RECORDER_ERROR_TOPIC)]
    assert sorted((e["topic"], bytes.fromhex(e["payload_hex"])) for e in errors) == sorted(
        recorded.published.malformed)
    assert {e["reason"] for e in errors} == {"not-json", "missing-fields"}


def summary_samples(path, topic):
    from recordings.reader import iter_samples
    return list(iter_samples(path, [topic]))


def test_metadata_has_run_and_versions(recorded):
    meta = read_metadata(recorded.path)
    assert meta["scenario"] == "synthetic" and meta["seed"] == 1 and meta["planner"] == "scripted"
    assert meta["log_time"] == "sim"
    assert {"mcap", "rerun-sdk", "eclipse-zenoh", "python"} <= set(meta["versions"])
    assert meta["argv"] == ["synthetic"]


def test_log_time_is_the_start_instant_plus_sim_time(recorded):
    from recordings.reader import iter_samples
    meta = read_metadata(recorded.path)
    start = meta["start_time_ns"]
    assert start > 1_700_000_000 * 10**9 and meta["start_time"].startswith("20")  # a real date
    for s in iter_samples(recorded.path, [t for t in recorded.tally.by_topic if t.startswith("frame/")]):
        assert s.log_time_ns == start + s.json()["sim_time_ns"]
        assert s.publish_time_ns == s.json()["wall_time_ns"]


def test_two_identical_runs_give_identical_frames(tmp_path, record):
    a = record(tmp_path / "a.mcap", moves=4, filler_frames=5)
    b = record(tmp_path / "b.mcap", moves=4, filler_frames=5)
    fa = [_frame_key(e) for e in read_frames(a.path)]
    fb = [_frame_key(e) for e in read_frames(b.path)]
    assert fa == fb and len(fa) == len(a.published.frames)


def test_rotation_by_duration_splits_and_reads_back(tmp_path, record):
    r = record(tmp_path / "rot.mcap", recorder_kwargs={"rotate_s": 1.0}, moves=6, filler_frames=4)
    parts = sorted(tmp_path.glob("rot_*.mcap"))
    assert len(parts) >= 3 and not (tmp_path / "rot.mcap").exists()
    assert [p.name for p in parts][:2] == ["rot_0001.mcap", "rot_0002.mcap"]
    assert [_frame_key(e) for e in read_frames(tmp_path / "rot.mcap")] == [
        _frame_key(e) for e in r.published.frames]
    s = summary(tmp_path / "rot.mcap")
    assert s.complete and dict(s.tally.frames_by_link) == r.published.frames_by_link()
    assert read_metadata(parts[-1])["scenario"] == "synthetic"  # every part is self-describing


def test_rotation_by_size(tmp_path, record):
    r = record(tmp_path / "size.mcap", recorder_kwargs={"rotate_bytes": 2000, "chunk_size": 1024},
               moves=8, filler_frames=40)
    parts = sorted(tmp_path.glob("size_*.mcap"))
    assert len(parts) >= 2
    assert len(list(read_frames(tmp_path / "size.mcap"))) == len(r.published.frames)


def test_truncated_files_give_a_prefix_of_the_frames(tmp_path, recorded):
    data = recorded.path.read_bytes()
    full = [_frame_key(e) for e in read_frames(recorded.path)]
    for cut in (8, 100, len(data) // 3, len(data) // 2, len(data) - 40, len(data) - 1):
        p = tmp_path / f"cut{cut}.mcap"
        p.write_bytes(data[:cut])
        got = [_frame_key(e) for e in read_frames(p)]
        assert got == full[:len(got)]
        s = summary(p)
        assert not s.complete and s.truncated

"""The recorder's own MCAP writer: every compression, read back by mcap's reader, by ours and
checked by ``rerun mcap check``; edited copies stay valid files."""

from __future__ import annotations

import subprocess

import pytest
from mcap.reader import make_reader

from edit import rewrite
from recordings.reader import iter_samples, summary
from recordings.recorder import Recorder


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_every_compression_reads_back(tmp_path, recorded, compression):
    out = tmp_path / f"{compression}.mcap"
    with Recorder(out, fleet="rectest", compression=compression, chunk_size=4096, time_source="sim") as rec:
        for s in iter_samples(recorded.path):
            rec.write(s.topic, s.data)
    with open(out, "rb") as f:
        reader = make_reader(f)
        got = [(ch.topic, m.data) for _, ch, m in reader.iter_messages(log_time_order=False)
               if ch.message_encoding == "json"]  # beside them: the derived foxglove/* channels
        stats = reader.get_summary().statistics
    want = [(s.topic, s.data) for s in iter_samples(recorded.path)]
    assert sorted(got) == sorted(want) and stats.chunk_count > 1
    s = summary(out)
    assert s.compression == [compression] and s.complete
    assert dict(s.tally.frames_by_link) == recorded.published.frames_by_link()


def test_an_edited_copy_is_a_valid_file(tmp_path, recorded, rerun_bin):
    out = tmp_path / "copy.mcap"
    dropped = rewrite(recorded.path, out, lambda s: None if s.topic.startswith("world/") else s.data)
    assert dropped == sum(n for t, n in recorded.tally.by_topic.items() if t.startswith("world/")) > 0
    res = subprocess.run([rerun_bin, "mcap", "check", str(out)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stdout + res.stderr
    assert summary(out).metadata["scenario"] == "synthetic"


def test_strict_and_fast_paths_record_the_same_file_contents(tmp_path, recorded):
    """The fast path (no JSON decoding of frames) keeps exactly what the careful one keeps."""
    outs = {}
    for strict in (False, True):
        out = outs[strict] = tmp_path / f"strict-{strict}.mcap"
        with Recorder(out, fleet="rectest", time_source="sim", strict=strict, start_ns=10**18) as rec:
            for s in iter_samples(recorded.path):
                rec.write(s.topic, s.data, receive_wall_ns=1)
    fast, careful = ([(s.topic, s.log_time_ns, s.publish_time_ns, s.data) for s in iter_samples(outs[k], derived=True)]
                     for k in (False, True))
    assert fast == careful  # the bus's samples and the foxglove/* channels derived from them
    assert sum(1 for s in fast if s[0] == "foxglove/log") == recorded.tally.frames
    assert summary(outs[False]).tally.to_dict() == summary(outs[True]).tally.to_dict()

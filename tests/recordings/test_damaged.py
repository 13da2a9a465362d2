"""Damaged and foreign files (issue: hardening): the tools never raise, recover what is
intact, say what was lost, and ``recover`` writes a file mcap's own reader opens."""

from __future__ import annotations

import random
import struct

import pytest
from mcap.reader import make_reader

from hexbench.cli import main
from recordings.reader import RecordingFile
from recordings.recover import recover

MUTATIONS = 200


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of the file's top-level records, after the magic."""
    out, i = [], 8
    while i + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, i)
        out.append((i, op, length))
        if op == 0x02:  # footer
            break
        i += 9 + length
    return out


def _mutate(data: bytes, rng: random.Random) -> bytes:
    """One seeded damage: bytes of a chunk body flipped, a length field or CRC rewritten, or
    the file cut."""
    b = bytearray(data)
    recs = _records(data)
    chunks = [r for r in recs if r[1] == 0x06] or recs
    off, op, length = rng.choice(chunks)
    what = rng.randrange(4)
    if what == 0:  # chunk body
        for _ in range(rng.randint(1, 16)):
            b[off + 9 + rng.randrange(max(length, 1))] ^= 1 << rng.randrange(8)
    elif what == 1:  # the record's length field
        struct.pack_into("<Q", b, off + 1, rng.choice([0, length // 2, length + 7, 2 ** 63 - 1,
                                                        rng.randrange(2 ** 64)]))
    elif what == 2:  # a chunk's CRC (after start/end times and size: offset 9 + 24)
        struct.pack_into("<I", b, off + 9 + 24, rng.randrange(2 ** 32))
    else:  # cut anywhere
        del b[rng.randrange(len(b)):]
    return bytes(b)


def test_mutated_recordings_never_crash_the_tools(tmp_path, pair_recording, capsys):
    rng = random.Random(31)
    data = pair_recording.read_bytes()
    intact = sum(1 for _ in RecordingFile(pair_recording).samples(derived=True))
    lost_reported = 0
    for k in range(MUTATIONS):
        bad = tmp_path / "bad.mcap"
        bad.write_bytes(_mutate(data, rng))
        code = main(["info", str(bad)])
        assert code in (0, 1)
        out = tmp_path / "out.mcap"
        r = recover(bad, out)
        with open(out, "rb") as f:  # mcap's own reader opens what recover wrote
            assert sum(1 for _ in make_reader(f).iter_messages()) == r.messages <= intact
        lost_reported += r.lost
        if k % 20 == 0:
            assert main(["replay", str(bad), "--rrd", str(tmp_path / "bad.rrd")]) == (1 if r.damaged else 0)
    capsys.readouterr()
    assert lost_reported > MUTATIONS // 2  # the damage was noticed, not silently passed


def test_a_damaged_chunk_is_skipped_and_counted(tmp_path, pair_recording, capsys):
    data = bytearray(pair_recording.read_bytes())
    off, _, length = next(r for r in _records(bytes(data)) if r[1] == 0x06)
    for i in range(off + 9 + 80, off + 9 + 100):  # in the compressed records
        data[i] ^= 0xFF
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert main(["info", str(bad)]) == 1
    err = capsys.readouterr().err
    assert f"damaged chunk at byte {off} skipped" in err and "message(s) lost" in err
    assert main(["replay", str(bad), "--rrd", str(tmp_path / "bad.rrd")]) == 1
    assert main(["recover", str(bad), str(tmp_path / "ok.mcap")]) == 1
    intact = sum(1 for _ in RecordingFile(pair_recording).samples(derived=True))
    with open(tmp_path / "ok.mcap", "rb") as f:
        got = sum(1 for _ in make_reader(f).iter_messages())
    assert 0 < got < intact


@pytest.mark.parametrize("content", [b"root:x:0:0:root:/root:/bin/bash\n", b"", b"\x89MCAP"])
def test_a_foreign_file_is_not_an_mcap_file(tmp_path, content, capsys):
    f = tmp_path / "x.mcap"
    f.write_bytes(content)
    for argv in (["info", str(f)], ["replay", str(f), "--rrd", str(tmp_path / "x.rrd")],
                 ["recover", str(f), str(tmp_path / "y.mcap")]):
        assert main(argv) == 2
        assert "is not an MCAP file" in capsys.readouterr().err

"""The IR medium's collision model at one receiver (``module_sim.air``): a pile-up taken a bin
at a time gives what visiting every byte gives — the same values, garbled flags and sources
for each new burst, and the same final value for every byte in the air."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from module_sim.air import Air

BYTE_NS = 33_333_333


def _play(bursts, bins_from: int):
    air = Air(bins_from=bins_from)
    arrived: dict[tuple[str, int, int], int] = {}
    returned = []
    counters: dict[str, int] = {}
    for src, t0, data, cut_at in bursts:
        n = counters[src] = counters.get(src, -1) + 1
        starts = [t0 + i * BYTE_NS for i in range(len(data))]
        values, corrupt, fixes, sources = air.collide(src, n, data, starts, BYTE_NS, t0)
        for s, b, i, v in fixes:
            arrived[(s, b, i)] = v
        for i, v in enumerate(values):
            arrived[(src, n, i)] = v
        returned.append((values, corrupt, sorted(sources)))
        air.add(src, n, values, corrupt, starts, BYTE_NS)
        if cut_at is not None and cut_at < len(data):
            v = air.cut(src, n, data, starts, BYTE_NS, cut_at, 0x0F)
            returned.append(("cut", v))
    return returned, arrived


_burst = st.tuples(st.sampled_from([f"m{i}.comm" for i in range(1, 40)]),
                   st.integers(0, 40 * BYTE_NS), st.binary(min_size=1, max_size=6),
                   st.one_of(st.none(), st.integers(0, 6)))


@settings(max_examples=300, deadline=None)
@given(st.lists(_burst, min_size=1, max_size=60).map(lambda bs: sorted(bs, key=lambda b: b[1])))
def test_bins_and_byte_by_byte_agree(bursts):
    assert _play(bursts, bins_from=0) == _play(bursts, bins_from=10**9)


def test_a_pile_up_of_identical_answers():
    """250 modules answering at once, a few microseconds apart: every byte garbled, each
    burst collides with all the others that overlap it."""
    bursts = [(f"m{i}.comm", 1_000 * i, b"\n\rM: ACK\x0b\n\r", None) for i in range(250)]
    fast, slow = _play(bursts, bins_from=48), _play(bursts, bins_from=10**9)
    assert fast == slow
    values, corrupt, sources = fast[0][-1]
    assert all(corrupt) and len(sources) == 249

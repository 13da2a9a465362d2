"""Fuzz benchmark (issue: hardening): a million frames, random, mutated and bit-flipped, into
the framers of every link, and a million bytes into a module's centre and side receivers,
with the Python programs and with the C firmware as the module's program. Nothing may raise.
Run alone: ``pytest -s tests/benchmarks/test_fuzz.py`` (``HEXBENCH_FUZZ_N`` scales it down).
Prints what went in and what came out.
"""

from __future__ import annotations

import os
import random
import time
from collections import Counter

import pytest

from bus import codec
from bus.codec import Link
from bus.framer import Framer
from bus.functions import FUNCTIONS

N = int(os.environ.get("HEXBENCH_FUZZ_N", "1000000"))


def _valid(rng: random.Random, link: Link) -> bytes:
    """A frame the link's grammar accepts."""
    if link is Link.PC:
        return codec.START + bytes([rng.choice(list(FUNCTIONS))]) + rng.randbytes(8) + codec.END
    if link is Link.UART0_DOWN:
        return codec.START + rng.randbytes(5) + codec.END
    if link is Link.CENTRE:
        return rng.choice([codec.encode_ack(rng.randrange(256), role=b"M: "),
                           codec.encode_banner(rng.choice(list(codec.BANNERS))),
                           codec.encode_position(rng.randrange(256), rng.randrange(-99, 100),
                                                 rng.randrange(-99, 100), rng.randrange(6),
                                                 localized=True, mobile=False, substrate=True)])
    if link is Link.SIDE:
        return codec.encode_msg1(rng.randrange(-99, 100), rng.randrange(-99, 100), rng.randrange(1, 7))
    if link is Link.DEBUG:
        return rng.choice([codec.encode_debug_msg(rng.randbytes(5)),
                           codec.encode_actuator_report([rng.random() < .5 for _ in range(6)],
                                                        [rng.choice((-1, 0, 1, 2)) for _ in range(6)])])
    return rng.choice([b"R", b"L", bytes([rng.randrange(256)])])


def _mutate(rng: random.Random, frame: bytes) -> bytes:
    how = rng.randrange(5)
    b = bytearray(frame)
    if how == 0:
        return rng.randbytes(rng.randrange(1, 24))  # random
    if how == 1 and b:  # bit flips
        for _ in range(rng.randrange(1, 4)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif how == 2 and b:  # truncated
        del b[rng.randrange(len(b)):]
    elif how == 3:  # a byte inserted or dropped
        i = rng.randrange(len(b) + 1)
        if rng.random() < 0.5 or not b:
            b.insert(i, rng.randrange(256))
        else:
            del b[min(i, len(b) - 1)]
    return bytes(b)  # how == 4: intact


def test_framers_take_a_million_frames():
    rng = random.Random(2026)
    links = list(Link)
    framers = {link: Framer(link) for link in links}
    kinds: Counter = Counter()
    fed = 0
    t = time.perf_counter()
    for k in range(N):
        link = links[k % len(links)]
        data = _mutate(rng, _valid(rng, link))
        fed += len(data)
        for timed in framers[link].feed(data, k):
            kinds[timed.frame.kind.value] += 1
    for f in framers.values():
        for timed in f.flush():
            kinds[timed.frame.kind.value] += 1
    wall = time.perf_counter() - t
    print(f"\n[fuzz] framers: {N} frames ({fed} bytes) over {len(links)} links in {wall:.1f} s; "
          f"out: {sum(kinds.values())} frames, {kinds['noise']} noise; by kind {dict(kinds)}; "
          "0 exceptions")
    assert kinds["noise"] > 0 and sum(kinds.values()) - kinds["noise"] > N // 4


@pytest.mark.parametrize("program", ["model", "firmware"])
def test_receivers_take_a_million_bytes(program):
    """Random bytes (with many '*' so the programs act on them) into the centre and the six
    side transceivers of one module, back to back at the IR baud rate."""
    from bus.clock import VirtualClock
    from bus.session import SessionOptions
    from bus.timing import byte_time_ns
    from bus.transport import Bus
    from module_sim.module import VirtualModule
    from module_sim.profiles import V2

    if program == "firmware":
        from bus.cheader import ensure_built
        ensure_built()
    rng = random.Random(7)
    bus = Bus(VirtualClock(), f"fuzz{program}", options=SessionOptions(isolated=True))
    try:
        m = VirtualModule(bus, 1, V2, program=program)
        out = Counter()
        hook = m.comm.uart1.on_tx

        def count(data, starts):
            out["bytes"] += len(data)
            out["acks"] += bytes(data).count(b"ACK")
            hook(data, starts)
        m.comm.uart1.on_tx = count
        m.power_up()
        clock, b = bus.clock, byte_time_ns(300)
        t0 = time.perf_counter()
        chunk = 10_000
        for start in range(0, N, chunk):
            base = clock.now_ns()
            for k in range(chunk):
                byte = 0x2A if rng.random() < 0.08 else rng.randrange(256)
                tr = 0 if rng.random() < 0.7 else rng.randrange(1, 7)
                at = base + (k + 1) * b
                clock.call_at(at, m._ir_rx, tr, byte, at - b, rng.random() < 0.01)
            clock.run(until_ns=base + (chunk + 1) * b)
        wall = time.perf_counter() - t0
        print(f"\n[fuzz] {program} module: {N} bytes into its transceivers ({N * b / 1e9:.0f} s of "
              f"sim time) in {wall:.1f} s; it answered {out['acks']} ACKs ({out['bytes']} bytes "
              f"out), {m.overruns} UART overruns, {m.side_bytes_heard} side bytes heard; 0 exceptions")
        assert out["acks"] > 0
    finally:
        bus.close()

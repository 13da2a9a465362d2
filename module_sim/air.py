"""The world's IR medium at one receiving transceiver: which bytes are in the air, and what
a new burst that overlaps them does to them (the collision model; the messages it leads to
are :mod:`bus.ir`'s ``garble`` and ``cut``).

The receiver is the ATmega162's USART (docs/physics.md, "IR bytes at a receiver"): the line is
low while any carrier is on (a start bit or a 0 data bit), so it carries the AND of every byte
in flight, bit by bit in time. The USART locks onto a byte's start bit and reads each data bit
as the majority of three samples in the middle of the bit (samples 8, 9 and 10 of 16), so a
byte arrives with bit k cleared when its own bit is 0 or when at least two of those three
instants fall where some other carrier holds the line low.
"""

from __future__ import annotations

from bisect import bisect_left, bisect_right, insort
from typing import Any

SAMPLES = (7, 8, 9)  # sixteenths of a bit after its edge: the USART's samples 8, 9 and 10


def sample_times(start: int, byte_ns: int, bit: int) -> tuple[int, int, int]:
    """When the receiver samples data bit ``bit`` (0 = LSB) of a byte starting at ``start``
    (the start bit is bit time 0, so data bit k is bit time k + 1)."""
    base = 16 * (bit + 1)
    return tuple(start + (base + s) * byte_ns // 160 for s in SAMPLES)  # type: ignore[return-value]


def low_spans(start: int, byte_ns: int, sent: int) -> list[tuple[int, int]]:
    """Where a byte's carrier holds the line low: its start bit and each run of 0 data bits
    (bit time j spans ``start + j*byte_ns//10`` to ``start + (j+1)*byte_ns//10``)."""
    out: list[tuple[int, int]] = []
    j = 0
    while j < 9:
        if j == 0 or not sent >> (j - 1) & 1:
            k = j + 1
            while k < 9 and not sent >> (k - 1) & 1:
                k += 1
            out.append((start + j * byte_ns // 10, start + k * byte_ns // 10))
            j = k
        else:
            j += 1
    return out


class Air:
    """What is in the air at one receiving transceiver, for the IR medium's collision model.

    Every cost is per byte, not per byte times the carriers it meets (a boot pile-up at the
    PC has hundreds of carriers in flight):

    * ``low``: where the line is held low, a sorted list of disjoint spans (the union of every
      carrier's :func:`low_spans`); a new byte's samples are looked up in it (O(log n)).
    * ``pending``: the samples of bytes in flight that still read high (1 bits not yet
      outvoted); a new carrier's low spans take the samples they cover out, each once.
    * ``clean``: bytes in flight no other transmitter overlaps yet; a new byte that overlaps
      one garbles it, once.
    * ``runs``: per transmitter, the spans its bytes cover, for a collision's sources.

    A transmitter is one UART: its own bytes never overlap. Only what is sent counts, so no
    order of learning of the bursts changes a byte's value (light from another shard comes a
    lockstep window late, after later light of its own shard).
    """

    __slots__ = ("keys", "members", "clean", "low_a", "low_b", "pending", "runs", "longest",
                 "_uid", "_stash", "_now")

    def __init__(self) -> None:
        self.keys: list[tuple[int, int, int]] = []  # (start, end, uid) of the bytes in flight
        # uid -> [src, burst, index, value, sent, start, end, lows per bit, corrupt]
        self.members: dict[int, list[Any]] = {}
        self.clean: list[tuple[int, int, int]] = []  # keys of the bytes not garbled yet
        self.low_a: list[int] = []  # the line's low spans: starts ...
        self.low_b: list[int] = []  # ... and ends
        self.pending: list[tuple[int, int, int]] = []  # (time, uid, bit): samples reading high
        self.runs: dict[str, tuple[list[int], list[int]]] = {}  # src -> its spans' starts, ends
        self.longest = 0
        self._uid = 0
        self._stash: list[list[int]] = []  # collide's low samples per byte and bit, for add
        self._now = 0  # collide's now: what ended before it is forgotten

    # -- the line --------------------------------------------------------------------------------
    def _is_low(self, t: int) -> bool:
        i = bisect_right(self.low_a, t) - 1
        return i >= 0 and self.low_b[i] > t

    def _hold_low(self, a: int, b: int, changed: dict[int, list[Any]]) -> None:
        """A carrier holds the line low from ``a`` to ``b``: merge the span into the line and
        outvote the samples it covers."""
        la, lb = self.low_a, self.low_b
        i = bisect_left(lb, a)  # first span ending at or after a
        j = bisect_right(la, b)  # spans starting at or before b
        if i < j:
            a, b = min(a, la[i]), max(b, lb[j - 1])
        la[i:j] = [a]
        lb[i:j] = [b]
        pending = self.pending
        p = bisect_left(pending, (a,))
        q = bisect_left(pending, (b,))
        for _t, uid, bit in pending[p:q]:
            m = self.members[uid]
            m[7][bit] += 1
            if m[7][bit] == 2:
                m[3] &= ~(1 << bit) & 0xFF
                changed[uid] = m
        del pending[p:q]

    def _forget(self, now: int) -> None:
        keys, longest = self.keys, self.longest
        if keys and keys[0][0] + longest <= now:
            cut = bisect_left(keys, (now - longest + 1,))
            for _s, _e, uid in keys[:cut]:
                del self.members[uid]
            del keys[:cut]
            del self.clean[:bisect_left(self.clean, (now - longest + 1,))]
        del self.pending[:bisect_left(self.pending, (now,))]
        k = bisect_right(self.low_b, now)
        del self.low_a[:k]
        del self.low_b[:k]

    def _overlapped(self, src: str, start: int, end: int) -> bool:
        """Does another transmitter's byte overlap ``start``..``end``?"""
        keys, members = self.keys, self.members
        for j in range(bisect_left(keys, (start - self.longest + 1,)), len(keys)):
            s, e, uid = keys[j]
            if s >= end:
                break
            if e > start and members[uid][0] != src:
                return True
        return False

    # -- the medium's interface ------------------------------------------------------------------
    def collide(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int,
                now: int) -> tuple[list[int], list[bool], list[list[Any]], set[str]]:
        """A new burst reaches this receiver: returns the values it arrives with, which bytes
        are garbled, the corrections to earlier bursts ``[src, burst, index, value]`` and the
        sources it collided with. :meth:`add` then puts it in the air."""
        self._forget(now)
        self._now = now
        values = list(data)
        corrupt = [False] * len(values)
        stash: list[list[int]] = []
        is_low = self._is_low
        for i, start in enumerate(starts):
            sent = values[i]
            lows = [0] * 8
            v = sent
            for bit in range(8):
                if sent >> bit & 1:
                    n = sum(1 for t in sample_times(start, byte_ns, bit) if is_low(t))
                    lows[bit] = n
                    if n >= 2:
                        v &= ~(1 << bit)
            stash.append(lows)
            values[i] = v
            corrupt[i] = self._overlapped(src, start, start + byte_ns)
        self._stash = stash
        changed: dict[int, list[Any]] = {}
        clean, longest = self.clean, self.longest
        for start in starts:  # the bytes this burst garbles for the first time
            end = start + byte_ns
            j = bisect_left(clean, (start - longest + 1,))
            while j < len(clean) and clean[j][0] < end:
                s, e, uid = clean[j]
                m = self.members[uid]
                if e > start and m[0] != src:
                    m[8] = True
                    changed[uid] = m
                    del clean[j]
                else:
                    j += 1
        for i, start in enumerate(starts):
            for a, b in low_spans(start, byte_ns, data[i]):
                self._hold_low(a, b, changed)
        fixes = [m[:4] for _uid, m in sorted(changed.items())]
        sources: set[str] = set()
        if True in corrupt:
            mine = _runs(starts, byte_ns)
            for other, (ra, rb) in list(self.runs.items()):
                k = bisect_right(rb, now)
                if k:
                    del ra[:k], rb[:k]
                if not ra:
                    del self.runs[other]
                    continue
                if other != src and any(_meets(ra, rb, a, b) for a, b in mine):
                    sources.add(other)
        return values, corrupt, fixes, sources

    def add(self, src: str, burst: int, sent: bytes, values: list[int], corrupt: list[bool],
            starts: list[int], byte_ns: int) -> None:
        """Put a forwarded burst's bytes in the air: what was ``sent`` and the values it
        arrives with (after :meth:`collide`, which has already held the line low for it)."""
        if byte_ns > self.longest:
            self.longest = byte_ns
        stash = self._stash if len(self._stash) == len(starts) else [[0] * 8 for _ in starts]
        self._stash = []
        is_low = self._is_low
        for i, start in enumerate(starts):
            self._uid += 1
            uid = self._uid
            key = (start, start + byte_ns, uid)
            insort(self.keys, key)
            self.members[uid] = [src, burst, i, values[i], sent[i], start, start + byte_ns,
                                 stash[i], corrupt[i]]
            if not corrupt[i]:
                insort(self.clean, key)
            for bit in range(8):
                if sent[i] >> bit & 1 and stash[i][bit] < 2:
                    for t in sample_times(start, byte_ns, bit):
                        if not is_low(t):
                            insort(self.pending, (t, uid, bit))
        ra, rb = self.runs.setdefault(src, ([], []))
        k = bisect_right(rb, self._now)  # its own light that has ended (a run with no collision
        if k:                            # is forgotten here, not by collide)
            del ra[:k], rb[:k]
        for a, b in _runs(starts, byte_ns):
            if rb and rb[-1] >= a and ra[-1] <= a:  # touches its last span: extend it
                rb[-1] = max(rb[-1], b)
            else:
                k = bisect_left(ra, a)
                ra.insert(k, a)
                rb.insert(k, b)

    def cut(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int, index: int,
            lost_mask: int | None) -> int | None:
        """A forwarded burst was cut short at byte ``index`` (see :func:`cut_message`): the
        bytes after it leave the air; if ``lost_mask`` is not None, the cut byte stays with
        those bits idle (1). Returns the value the cut byte now arrives with (or None).
        Rare (a multiplexer moving mid-burst): the line is rebuilt from what stays."""
        result = None
        gone: set[int] = set()
        for i in range(index, len(starts)):
            end = starts[i] + byte_ns
            j = bisect_left(self.keys, (starts[i], end))
            partial = i == index and lost_mask is not None
            mine = None
            while j < len(self.keys) and self.keys[j][:2] == (starts[i], end):
                m = self.members[self.keys[j][2]]
                if m[0] == src and m[1] == burst:
                    mine = self.keys[j]
                    break
                j += 1
            if mine is None:
                if partial:
                    result = data[i] | lost_mask  # type: ignore[operator]
                continue
            m = self.members[mine[2]]
            gone.add(mine[2])
            if partial:
                m[3] |= lost_mask
                m[4] |= lost_mask  # the bits that did not go out here are idle
                m[8] = True
                result = m[3]
            else:
                del self.keys[j]
                del self.members[mine[2]]
        if not gone:
            return result
        self.clean = [k for k in self.clean if k[2] not in gone]
        self.pending = [p for p in self.pending if p[1] not in gone]
        spans = sorted(s for _a, _b, uid in self.keys
                       for s in low_spans(self.members[uid][5], self.members[uid][6] -
                                          self.members[uid][5], self.members[uid][4]))
        self.low_a, self.low_b = [], []
        for a, b in spans:
            if self.low_b and a <= self.low_b[-1]:
                self.low_b[-1] = max(self.low_b[-1], b)
            else:
                self.low_a.append(a)
                self.low_b.append(b)
        ra, rb = [], []
        for a, b in _runs(sorted(self.members[uid][5] for _a, _b, uid in self.keys
                                 if self.members[uid][0] == src), byte_ns):
            ra.append(a)
            rb.append(b)
        self.runs[src] = (ra, rb)
        return result


def _runs(starts: list[int], byte_ns: int) -> list[tuple[int, int]]:
    """The spans a burst's bytes cover, touching bytes merged."""
    out: list[list[int]] = []
    for s in starts:
        if out and s <= out[-1][1]:
            out[-1][1] = max(out[-1][1], s + byte_ns)
        else:
            out.append([s, s + byte_ns])
    return [(a, b) for a, b in out]


def _meets(ra: list[int], rb: list[int], a: int, b: int) -> bool:
    """Do the sorted disjoint spans ``ra``/``rb`` overlap ``a``..``b``?"""
    i = bisect_right(rb, a)
    return i < len(ra) and ra[i] < b

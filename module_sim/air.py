"""The world's IR medium at one receiving transceiver: which bytes are in the air, and what
a new burst that overlaps them does to them (the collision model; the messages it leads to
are :mod:`bus.ir`'s ``garble`` and ``cut``)."""

from __future__ import annotations

from bisect import bisect_left
from typing import Any


class Air:
    """What is in the air at one receiving transceiver: the bytes forwarded to it that have not
    ended yet, for the IR medium's collision model.

    Bytes are kept in slots by exact time span ``(start, end)``; in a slot, bytes known to be
    garbled are grouped by value. A byte arrives as the AND of what it and every byte
    overlapping it were sent as (the line is low while either carrier is on): a new byte that
    overlaps bytes in the air arrives as the AND of itself and what they were sent as, and each
    of them becomes the AND of itself and the new byte. Only the bytes sent count, never what
    an earlier collision made of them, so the result does not depend on the order the medium
    learns of the bursts (light from another shard comes a lockstep window late, after later
    light of its own shard). Only bytes whose value or garbled state changes need a
    correction, so a pile-up of n identical transmissions costs O(n), not O(n^2).
    """

    __slots__ = ("keys", "slots", "longest")

    def __init__(self) -> None:
        self.keys: list[tuple[int, int]] = []  # slot spans, sorted
        # parallel to keys: [clean members, {value: garbled members}, sources, AND, OR of the
        # garbled values, AND of what the members were sent as];
        # member = [src, burst, index, value, sent]
        self.slots: list[list[Any]] = []
        self.longest = 0

    def collide(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int,
                now: int) -> tuple[list[int], list[bool], list[list[Any]], set[str]]:
        """A new burst reaches this receiver: returns the values it arrives with, which bytes
        are garbled, the corrections to earlier bursts ``[src, burst, index, value]`` and the
        sources it collided with. :meth:`add` then puts it in the air."""
        keys, slots = self.keys, self.slots
        longest = self.longest
        if keys and keys[0][0] + longest <= now:  # forget what has ended
            cut = bisect_left(keys, (now - longest + 1,))
            del keys[:cut]
            del slots[:cut]
        values = list(data)
        corrupt = [False] * len(values)
        fixes: list[list[Any]] = []
        hits: list[set[str]] = []
        if keys:
            nkeys = len(keys)
            for i, start in enumerate(starts):
                end = start + byte_ns
                v = values[i]
                acc = v
                hit = False
                for j in range(bisect_left(keys, (start - longest + 1,)), nkeys):
                    span = keys[j]
                    if span[0] >= end:
                        break
                    if span[1] <= start:
                        continue
                    slot = slots[j]
                    clean, garbled, srcs, s_and, s_or, s_sent = slot
                    if len(srcs) <= 1 and (not srcs or src in srcs):
                        continue  # empty, or a transmitter never collides with itself (one UART)
                    hit = True
                    hits.append(srcs)
                    acc &= s_sent
                    if s_or & v != s_or:  # some known-garbled bytes change again
                        for w in [w for w in garbled if w & v != w]:
                            members = garbled.pop(w)
                            nw = w & v
                            for m in members:
                                m[3] = nw
                                fixes.append(m[:4])
                            garbled.setdefault(nw, []).extend(members)
                        slot[4] = s_or & v
                        slot[3] = s_and & v
                    if clean:  # first collision of these bytes
                        a, o = slot[3], slot[4]
                        for m in clean:
                            nw = m[3] & v
                            m[3] = nw
                            fixes.append(m[:4])
                            garbled.setdefault(nw, []).append(m)
                            a &= nw
                            o |= nw
                        slot[3], slot[4] = a, o
                        clean.clear()
                if hit:
                    values[i] = acc
                    corrupt[i] = True
        return values, corrupt, fixes, set().union(*hits) if hits else set()

    def cut(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int, index: int,
            lost_mask: int | None) -> int | None:
        """A forwarded burst was cut short at byte ``index`` (see :func:`cut_message`): the
        bytes after it leave the air; if ``lost_mask`` is not None, the cut byte stays with
        those bits idle (1). Returns the value the cut byte now arrives with (or None)."""
        keys, slots = self.keys, self.slots
        result = None
        for i in range(index, len(starts)):
            span = (starts[i], starts[i] + byte_ns)
            j = bisect_left(keys, span)
            partial = i == index and lost_mask is not None
            if j >= len(keys) or keys[j] != span:
                if partial:
                    result = data[i] | lost_mask
                continue
            slot = slots[j]
            clean, garbled = slot[0], slot[1]
            mine = [m for m in clean if m[0] == src and m[1] == burst]
            clean[:] = [m for m in clean if not (m[0] == src and m[1] == burst)]
            for w in list(garbled):
                ms = garbled[w]
                mine += [m for m in ms if m[0] == src and m[1] == burst]
                ms[:] = [m for m in ms if not (m[0] == src and m[1] == burst)]
                if not ms:
                    del garbled[w]
            if partial:
                for m in mine:
                    m[3] |= lost_mask
                    m[4] |= lost_mask  # the bits that did not go out here are idle
                    garbled.setdefault(m[3], []).append(m)
                    result = m[3]
                if result is None:
                    result = data[i] | lost_mask
            slot[2] = {m[0] for m in clean} | {m[0] for ms in garbled.values() for m in ms}
            slot[3], slot[4], slot[5] = 0xFF, 0, 0xFF
            for w in garbled:
                slot[3] &= w
                slot[4] |= w
            for m in clean:
                slot[5] &= m[4]
            for ms in garbled.values():
                for m in ms:
                    slot[5] &= m[4]
        return result

    def add(self, src: str, burst: int, sent: bytes, values: list[int], corrupt: list[bool],
            starts: list[int], byte_ns: int) -> None:
        """Put a forwarded burst's bytes in the air: what was ``sent`` and the values it
        arrives with."""
        keys, slots = self.keys, self.slots
        if byte_ns > self.longest:
            self.longest = byte_ns
        for i, start in enumerate(starts):
            span = (start, start + byte_ns)
            j = bisect_left(keys, span)
            if j < len(keys) and keys[j] == span:
                slot = slots[j]
            else:
                slot = [[], {}, set(), 0xFF, 0x00, 0xFF]
                keys.insert(j, span)
                slots.insert(j, slot)
            v = values[i]
            m = [src, burst, i, v, sent[i]]
            slot[5] &= sent[i]
            if corrupt[i]:
                slot[1].setdefault(v, []).append(m)
                slot[3] &= v
                slot[4] |= v
            else:
                slot[0].append(m)
            slot[2].add(src)

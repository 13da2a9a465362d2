"""The world's IR medium at one receiving transceiver: which bytes are in the air, and what
a new burst that overlaps them does to them (the collision model; the messages it leads to
are :mod:`bus.ir`'s ``garble`` and ``cut``)."""

from __future__ import annotations

from bisect import bisect_left, insort
from typing import Any

# A slot: [start, end, clean members, {value: garbled members}, sources, AND, OR of the garbled
# values]; a member: [src, burst, index, value].
_START, _END, _CLEAN, _GARBLED, _SRCS, _AND, _OR = range(7)
# A bin: [slots, AND of the slots' ANDs, OR of their ORs, clean members, sources, empty slots, exact]
_SLOTS, _BAND, _BOR, _BCLEAN, _BSRCS, _BEMPTY, _EXACT = range(7)


class Air:
    """What is in the air at one receiving transceiver: the bytes forwarded to it that have not
    ended yet, for the IR medium's collision model.

    Bytes are kept in slots by exact time span ``(start, end)``; in a slot, bytes known to be
    garbled are grouped by value. A new byte that overlaps bytes in the air arrives as the AND
    of itself and all of them, and each of them becomes the AND of itself and the new byte
    (the line is low while either carrier is on). Only bytes whose value or garbled state
    changes need a correction.

    Slots are filed in bins of an eighth of a byte time by start. When a byte overlaps many
    slots (a pile-up: hundreds of modules answering the PC at once), a bin that lies wholly
    inside the overlap and that the new byte cannot change (no clean byte in it, no bit of its
    garbled values that the new byte clears, no byte of the same transmitter) is taken whole
    from its aggregates; the others are visited slot by slot. Windows of fewer than
    :attr:`bins_from` (48) slots are visited slot by slot in span order, as the model has always
    done, so small fleets get byte-identical corrections.
    """

    __slots__ = ("bins", "order", "width", "uniform", "longest", "bins_from")

    def __init__(self, bins_from: int = 48) -> None:
        self.bins_from = bins_from  # overlap windows with at least this many slots use the bins
        self.bins: dict[int, list[Any]] = {}
        self.order: list[int] = []  # bin numbers, sorted (to forget old ones)
        self.width = 0  # bin width (ns): an eighth of the first byte time seen
        self.uniform = True  # every byte seen has the same length (bins may be taken whole)
        self.longest = 0

    # -- bins ------------------------------------------------------------------------------------
    def _bin(self, k: int) -> list[Any]:
        b = self.bins.get(k)
        if b is None:
            b = self.bins[k] = [[], 0xFF, 0, 0, set(), 0, True]
            insort(self.order, k)
        return b

    @staticmethod
    def _refresh(b: list[Any]) -> None:
        """Recompute a bin's aggregates from its slots."""
        a, o, clean, empty = 0xFF, 0, 0, 0
        srcs: set[str] = set()
        for slot in b[_SLOTS]:
            a &= slot[_AND]
            o |= slot[_OR]
            clean += len(slot[_CLEAN])
            if slot[_SRCS]:
                srcs |= slot[_SRCS]
            else:
                empty += 1
        b[_BAND], b[_BOR], b[_BCLEAN], b[_BSRCS], b[_BEMPTY], b[_EXACT] = a, o, clean, srcs, empty, True

    def _forget(self, now: int) -> None:
        """Drop the bins whose slots have all ended (a slot is at most ``longest`` long)."""
        order = self.order
        if order and self.width:
            cut = bisect_left(order, (now - self.longest) // self.width - 1)
            if cut:
                for k in order[:cut]:
                    del self.bins[k]
                del order[:cut]

    # -- a new burst -------------------------------------------------------------------------------
    def collide(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int,
                now: int) -> tuple[list[int], list[bool], list[list[Any]], set[str]]:
        """A new burst reaches this receiver: returns the values it arrives with, which bytes
        are garbled, the corrections to earlier bursts ``[src, burst, index, value]`` and the
        sources it collided with. :meth:`add` then puts it in the air."""
        self._forget(now)
        values = list(data)
        corrupt = [False] * len(values)
        fixes: list[list[Any]] = []
        hits: list[set[str]] = []
        if not self.bins:
            return values, corrupt, fixes, set()
        width, longest, bins = self.width, self.longest, self.bins
        wholesale = self.uniform and byte_ns == longest
        for i, start in enumerate(starts):
            end = start + byte_ns
            v = values[i]
            k0, k1 = (start - longest + 1) // width, (end - 1) // width
            window = [bins[k] for k in range(k0, k1 + 1) if k in bins]
            if not window:
                continue
            acc, hit = v, False
            if wholesale and sum(len(b[_SLOTS]) for b in window) >= self.bins_from:
                lo, hi = start - byte_ns + 1, end  # slot starts that overlap: lo <= a < hi
                for k, b in zip([k for k in range(k0, k1 + 1) if k in bins], window):
                    if k * width >= lo and (k + 1) * width <= hi:  # wholly inside the overlap
                        if not b[_EXACT]:
                            self._refresh(b)
                        if (not b[_BCLEAN] and not b[_BEMPTY] and src not in b[_BSRCS]
                                and b[_BOR] & v == b[_BOR]):
                            if b[_SLOTS]:  # every slot overlaps, is foreign and stays as it is
                                hit = True
                                hits.append(b[_BSRCS])
                                acc &= b[_BAND]
                            continue
                    a, h = self._visit(b[_SLOTS], src, start, end, v, fixes, hits)
                    if h:
                        acc &= a
                        hit = True
                        self._refresh(b)
            else:
                slots = sorted((s for b in window for s in b[_SLOTS]), key=_span)
                a, hit = self._visit(slots, src, start, end, v, fixes, hits)
                if hit:
                    acc &= a
                    for b in window:
                        b[_EXACT] = False
            if hit:
                values[i] = acc
                corrupt[i] = True
        return values, corrupt, fixes, set().union(*hits) if hits else set()

    @staticmethod
    def _visit(slots: list[list[Any]], src: str, start: int, end: int, v: int,
               fixes: list[list[Any]], hits: list[set[str]]) -> tuple[int, bool]:
        """The new byte ``v`` over ``[start, end)`` against each of ``slots`` that overlaps it:
        the AND of what it meets (with ``v``), whether it met anything; slots updated."""
        acc = v
        hit = False
        for slot in slots:
            if slot[_START] >= end or slot[_END] <= start:
                continue
            srcs = slot[_SRCS]
            if len(srcs) <= 1 and (not srcs or src in srcs):
                continue  # empty, or a transmitter never collides with itself (one UART)
            hit = True
            hits.append(srcs)
            acc &= slot[_AND]
            garbled = slot[_GARBLED]
            s_or = slot[_OR]
            if s_or & v != s_or:  # some known-garbled bytes change again
                for w in [w for w in garbled if w & v != w]:
                    members = garbled.pop(w)
                    nw = w & v
                    for m in members:
                        m[3] = nw
                        fixes.append(m[:])
                    garbled.setdefault(nw, []).extend(members)
                slot[_OR] = s_or & v
                slot[_AND] &= v
            clean = slot[_CLEAN]
            if clean:  # first collision of these bytes
                a, o = slot[_AND], slot[_OR]
                for m in clean:
                    acc &= m[3]
                    nw = m[3] & v
                    m[3] = nw
                    fixes.append(m[:])
                    garbled.setdefault(nw, []).append(m)
                    a &= nw
                    o |= nw
                slot[_AND], slot[_OR] = a, o
                clean.clear()
        return acc, hit

    # -- a burst cut short ------------------------------------------------------------------------
    def _slot(self, start: int, end: int) -> tuple[list[Any] | None, list[Any] | None]:
        b = self.bins.get(start // self.width) if self.width else None
        if b is None:
            return None, None
        for slot in b[_SLOTS]:
            if slot[_START] == start and slot[_END] == end:
                return b, slot
        return b, None

    def cut(self, src: str, burst: int, data: bytes, starts: list[int], byte_ns: int, index: int,
            lost_mask: int | None) -> int | None:
        """A forwarded burst was cut short at byte ``index`` (see :func:`cut_message`): the
        bytes after it leave the air; if ``lost_mask`` is not None, the cut byte stays with
        those bits idle (1). Returns the value the cut byte now arrives with (or None)."""
        result = None
        for i in range(index, len(starts)):
            b, slot = self._slot(starts[i], starts[i] + byte_ns)
            partial = i == index and lost_mask is not None
            if slot is None:
                if partial:
                    result = data[i] | lost_mask
                continue
            clean, garbled = slot[_CLEAN], slot[_GARBLED]
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
                    garbled.setdefault(m[3], []).append(m)
                    result = m[3]
                if result is None:
                    result = data[i] | lost_mask
            slot[_SRCS] = {m[0] for m in clean} | {m[0] for ms in garbled.values() for m in ms}
            slot[_AND], slot[_OR] = 0xFF, 0
            for w in garbled:
                slot[_AND] &= w
                slot[_OR] |= w
            assert b is not None
            b[_EXACT] = False
        return result

    # -- into the air --------------------------------------------------------------------------------
    def add(self, src: str, burst: int, values: list[int], corrupt: list[bool], starts: list[int],
            byte_ns: int) -> None:
        """Put a forwarded burst's bytes (with the values it arrives with) in the air."""
        if not self.width:
            self.width = max(1, byte_ns // 8)
        if self.longest and byte_ns != self.longest:
            self.uniform = False
        if byte_ns > self.longest:
            self.longest = byte_ns
        for i, start in enumerate(starts):
            end = start + byte_ns
            b = self._bin(start // self.width)
            slot = None
            for s in b[_SLOTS]:
                if s[_START] == start and s[_END] == end:
                    slot = s
                    break
            if slot is None:
                slot = [start, end, [], {}, set(), 0xFF, 0x00]
                b[_SLOTS].append(slot)
            v = values[i]
            m = [src, burst, i, v]
            if corrupt[i]:
                slot[_GARBLED].setdefault(v, []).append(m)
                slot[_AND] &= v
                slot[_OR] |= v
                b[_BAND] &= v
                b[_BOR] |= v
            else:
                slot[_CLEAN].append(m)
                b[_BCLEAN] += 1
            slot[_SRCS].add(src)
            b[_BSRCS].add(src)


def _span(slot: list[Any]) -> tuple[int, int]:
    return slot[_START], slot[_END]

"""Streaming framers: bytes in, frames out, one per link kind.

A framer is fed bytes in chunks of any size (one byte at a time is fine) and
yields frames as soon as they are complete and unambiguous. Bytes that cannot
belong to a frame become ``noise`` frames with the reason, and the framer
resynchronises at the next position where a frame can start. It never raises
on input bytes. The grammar is :data:`bus.codec.GRAMMARS`.
"""

from __future__ import annotations

from dataclasses import dataclass

from .codec import GRAMMARS, Frame, Link, Match, explain, frame_from_template, match, noise


@dataclass(frozen=True)
class Timed:
    """A frame with the times of its first and last byte (ns, any time base)."""

    frame: Frame
    t_first_ns: int
    t_last_ns: int


class Framer:
    """Incremental framer for one link. ``feed`` returns the frames completed so far."""

    def __init__(self, link: Link | str, *, max_noise: int = 64) -> None:
        self.link = Link(link)
        self._grammar = GRAMMARS[self.link]
        self._buf = bytearray()
        self._times: list[int] = []
        self._noise = bytearray()
        self._noise_t: list[int] = []
        self._noise_reason = ""
        self._max_noise = max_noise
        self._need = 1  # bytes the buffer must hold before matching is worth trying
        # While waiting for more bytes: the templates still possible for the bytes at the head
        # of the buffer, the longest complete one so far, and the position of the next byte.
        # Matching is positional (a template that failed on a prefix fails on every extension;
        # one that matched keeps its match), so each new byte is checked once per live template.
        self._alive: list | None = None
        self._best: tuple = (0, None)
        self._at = 0
        self._first = _first_byte_table(self.link)
        self._first1 = _FIRST1[self.link]
        self._known = _KNOWN.setdefault(self.link, {})  # shared by the framers of a link

    def feed(self, data: bytes | bytearray | int, t_ns: int | list[int] = 0) -> list[Timed]:
        """Add bytes (with one time for all, or one per byte) and return completed frames."""
        if isinstance(data, int):
            data = bytes([data & 0xFF])
        times = t_ns if isinstance(t_ns, list) else [t_ns] * len(data)
        out: list[Timed] = []
        if len(data) > 1 and len(times) == len(data) and self._chunk(data, times, out):
            return out
        for b, t in zip(data, times):
            self._buf.append(b)
            self._times.append(t)
            if len(self._buf) >= self._need:
                self._scan(out, final=False)
        return out

    def _chunk(self, data, times: list[int], out: list[Timed]) -> bool:
        """Fast path for a chunk that ends inside or exactly at the end of one frame (the
        common case: a UART write is a frame or part of one). Returns False, having changed
        nothing, when the byte-by-byte path is needed (a frame or noise ends inside it)."""
        buf = self._buf
        if buf:
            if self._alive is None or self._at != len(buf):
                return False
            cands, (best_len, best_tpl) = self._alive, self._best
            whole = bytes(buf) + bytes(data)
        else:
            # from an empty buffer the outcome depends on the bytes alone: most writes repeat
            whole = bytes(data)
            known = self._known.get(whole)
            if known is not None:
                return self._replay(known, whole, times, out)
            cands, best_len, best_tpl = self._first[data[0]], 0, None
        n_all = len(whole)
        still, full = [], False
        for pat, tpl in cands:
            m, n = match(tpl, whole)
            if m is Match.OK:
                if n == n_all:
                    full = True
                if n > best_len:
                    best_len, best_tpl = n, tpl
            elif m is Match.NEED:
                still.append((pat, tpl))
        # Byte by byte, a frame or noise is emitted at the first length where no template
        # still needs more bytes; a template alive at the end was alive at every length before.
        if not still and not full:
            if not buf:
                self._remember(whole, (0, None, None))
            return False
        if not buf:  # the outcome of these bytes from an empty buffer, kept
            outcome = (2, still, (best_len, best_tpl)) if still else \
                (1, frame_from_template(self.link, best_tpl, whole), None)
            self._remember(whole, outcome)
            return self._replay(outcome, whole, times, out)
        buf += data
        self._times += times
        if still:
            self._alive, self._best, self._at, self._need = still, (best_len, best_tpl), n_all, n_all + 1
            return True
        self._alive = None
        self._noise_emit(out)
        out.append(Timed(frame_from_template(self.link, best_tpl, whole), self._times[0],
                         self._times[-1]))
        buf.clear()
        self._times.clear()
        self._need = 1
        return True

    def _remember(self, whole: bytes, outcome: tuple) -> None:
        if len(self._known) >= _KNOWN_MAX:
            self._known.clear()
        self._known[whole] = outcome

    def _replay(self, outcome: tuple, whole: bytes, times: list[int], out: list[Timed]) -> bool:
        """What ``_chunk`` does with ``whole`` from an empty buffer, as it did the first time."""
        kind, a, b = outcome
        if kind == 0:
            return False
        if kind == 2:  # a frame may still complete: wait for more
            self._buf += whole
            self._times += times
            self._alive, self._best, self._at, self._need = a, b, len(whole), len(whole) + 1
            return True
        self._alive = None
        self._noise_emit(out)
        out.append(Timed(a, times[0], times[-1]))  # frames are immutable: one serves every time
        self._need = 1
        return True

    def flush(self) -> list[Timed]:
        """End of stream (or a long silence): whatever is pending becomes frames or noise."""
        out: list[Timed] = []
        self._scan(out, final=True)
        while self._buf:  # a truncated frame at the end
            self._noise_add(1, explain(self.link, bytes(self._buf)))
            self._scan(out, final=True)
        self._noise_emit(out)
        return out

    @property
    def idle(self) -> bool:
        """Nothing held: the next byte starts a frame (no bytes waiting, no noise to emit)."""
        return not self._buf and not self._noise

    @property
    def pending(self) -> bytes:
        return bytes(self._noise + self._buf)

    def waiting(self) -> tuple[int, list[int]] | None:
        """Where the next byte lands: ``(0, [])`` with nothing held, ``(held, alive)`` while
        the ``held`` bytes are a prefix of the templates ``alive`` (indexes into
        :func:`patterns`) and nothing is emitted until one of them can no longer grow;
        None if neither holds. A byte that keeps some template of ``alive`` (all those of
        :func:`patterns` whose pattern takes it at ``held``) longer than ``held + 1`` is only
        held: :mod:`module_sim.core` needs no Python for it."""
        if not self._buf:
            return 0, []
        if self._alive is None or self._at != len(self._buf):
            return None
        index = _INDEX[self.link]
        return len(self._buf), [index[pat] for pat, _ in self._alive]

    def _scan(self, out: list[Timed], final: bool) -> None:
        while self._buf:
            buf = self._buf
            p = len(buf) - 1
            if self._alive is not None and self._at == p:
                # one byte more than when we last waited: only check it, template by template
                byte = buf[p]
                best_len, best_tpl = self._best
                still = []
                for pat, tpl in self._alive:
                    e = pat[p]
                    if e < 0 or e == byte:
                        if len(pat) == p + 1:
                            if p + 1 > best_len:
                                best_len, best_tpl = p + 1, tpl
                        else:
                            still.append((pat, tpl))
            elif p == 0:  # a lone first byte: the table already knows
                best_len, best_tpl, still = self._first1[buf[0]]
            else:
                best_len, best_tpl, still = 0, None, []
                for pat, tpl in self._first[buf[0]]:
                    m, n = match(tpl, buf)
                    if m is Match.OK:
                        if n > best_len:
                            best_len, best_tpl = n, tpl
                    elif m is Match.NEED:
                        still.append((pat, tpl))
            if still and not final:
                # A longer frame may still complete: wait, unless a frame is already complete
                # and every pending alternative is shorter (never the case in our grammars).
                self._need = len(buf) + 1
                self._alive, self._best, self._at = still, (best_len, best_tpl), len(buf)
                return
            self._alive = None  # the head of the buffer moves on
            if best_tpl is None:
                self._noise_add(1, explain(self.link, bytes(self._buf)) if not self._noise else "")
                if len(self._noise) >= self._max_noise:
                    self._noise_emit(out)
                continue
            self._noise_emit(out)
            raw = bytes(self._buf[:best_len])
            out.append(Timed(frame_from_template(self.link, best_tpl, raw),
                             self._times[0], self._times[best_len - 1]))
            del self._buf[:best_len]
            del self._times[:best_len]
        self._need = 1

    def _noise_add(self, n: int, reason: str) -> None:
        self._alive = None
        if not self._noise:
            self._noise_reason = reason
        self._noise += self._buf[:n]
        self._noise_t += self._times[:n]
        del self._buf[:n]
        del self._times[:n]

    def _noise_emit(self, out: list[Timed]) -> None:
        if self._noise:
            out.append(Timed(noise(self.link, bytes(self._noise), self._noise_reason),
                             self._noise_t[0], self._noise_t[-1]))
            self._noise.clear()
            self._noise_t.clear()


#: per link: what a chunk fed to an empty framer gives (``Framer._replay``); bounded
_KNOWN: dict[Link, dict[bytes, tuple]] = {}
_KNOWN_MAX = 1 << 14
_FIRST: dict[Link, list[tuple]] = {}
_FIRST1: dict[Link, list[tuple]] = {}
_INDEX: dict[Link, dict[tuple[int, ...], int]] = {}  # per link: pattern -> its index (patterns)


def patterns(link: Link) -> tuple[list[tuple[int, ...]], list[list[int]]]:
    """The templates of ``link`` as patterns (the byte expected at each offset, -1 for a free
    byte), in grammar order, and for each first byte the indexes of those that do not fail
    on it (what :meth:`Framer.waiting` counts in)."""
    table = _first_byte_table(link)
    index = _INDEX[link]
    pats = sorted(index, key=index.__getitem__)
    return pats, [[index[pat] for pat, _ in c] for c in table]


def _first_byte_table(link: Link) -> list[tuple]:
    """For each possible first byte, the templates of ``link`` (in grammar order) that do not
    fail on it, each with its pattern: the expected byte at each offset, -1 for a free byte."""
    table = _FIRST.get(link)
    if table is None:
        pats = [(tuple(t.head) + (-1,) * t.n_any + tuple(t.tail), t) for t in GRAMMARS[link]]
        index = _INDEX[link] = {}
        for pat, _ in pats:
            index.setdefault(pat, len(index))
        table = _FIRST[link] = [tuple((pat, t) for pat, t in pats
                                      if match(t, bytes([b]))[0] is not Match.FAIL)
                                for b in range(256)]
        # the result of scanning a one-byte buffer: (best length, best template, still possible)
        _FIRST1[link] = [(1, next(t for pat, t in c if len(pat) == 1), [x for x in c if len(x[0]) > 1])
                         if any(len(pat) == 1 for pat, _ in c) else (0, None, [x for x in c if len(x[0]) > 1])
                         for c in table]
    return table


def frames(link: Link | str, data: bytes) -> list[Frame]:
    """All frames in a complete byte string (convenience for tools and tests)."""
    f = Framer(link)
    return [t.frame for t in f.feed(data) + f.flush()]

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

    def feed(self, data: bytes | bytearray | int, t_ns: int | list[int] = 0) -> list[Timed]:
        """Add bytes (with one time for all, or one per byte) and return completed frames."""
        if isinstance(data, int):
            data = bytes([data & 0xFF])
        times = t_ns if isinstance(t_ns, list) else [t_ns] * len(data)
        out: list[Timed] = []
        for b, t in zip(data, times):
            self._buf.append(b)
            self._times.append(t)
            if len(self._buf) >= self._need:
                self._scan(out, final=False)
        return out

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
    def pending(self) -> bytes:
        return bytes(self._noise + self._buf)

    def _scan(self, out: list[Timed], final: bool) -> None:
        while self._buf:
            best_len, best_tpl, need = 0, None, False
            for tpl in self._grammar:
                m, n = match(tpl, self._buf)
                if m is Match.OK and n > best_len:
                    best_len, best_tpl = n, tpl
                elif m is Match.NEED:
                    need = True
            if need and not final:
                # A longer frame may still complete: wait, unless a frame is already complete
                # and every pending alternative is shorter (never the case in our grammars).
                self._need = len(self._buf) + 1
                return
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


def frames(link: Link | str, data: bytes) -> list[Frame]:
    """All frames in a complete byte string (convenience for tools and tests)."""
    f = Framer(link)
    return [t.frame for t in f.feed(data) + f.flush()]

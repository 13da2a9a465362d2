"""Byte times on a serial line: per-byte wire times for bytes handed over in chunks.

On the wire each 8N1 byte takes ``10 / baud`` seconds, and a byte cannot end sooner than
one byte time after the previous one. Two cases:

* bytes *received* from a UART already crossed the wire: :meth:`ByteTimes.ends` stamps the
  last byte of a chunk with its arrival and earlier ones one byte time apart before it;
* bytes handed over all at once by a pseudo-terminal have still to cross the (emulated)
  wire: :meth:`ByteTimes.sent` starts the first at its arrival and paces the rest.

Both never put two bytes closer together than the baud rate allows.
"""

from __future__ import annotations

from bus.timing import byte_time_ns


class ByteTimes:
    """Stop-bit times of bytes on one line at ``baud``."""

    def __init__(self, baud: int) -> None:
        self.baud = baud
        self.byte_ns = byte_time_ns(baud)
        self._last_end: int | None = None

    def ends(self, n: int, arrived_ns: int) -> list[int]:
        """Stop-bit times of ``n`` bytes that arrived together at ``arrived_ns``."""
        out = []
        for k in range(n):
            end = arrived_ns - (n - 1 - k) * self.byte_ns
            if self._last_end is not None:
                end = max(end, self._last_end + self.byte_ns)
            out.append(end)
            self._last_end = end
        return out

    def sent(self, n: int, handed_ns: int) -> list[int]:
        """Start-bit times of ``n`` bytes handed to the line together at ``handed_ns``: the
        first starts then (or when the previous byte ends), the others back to back."""
        start = handed_ns if self._last_end is None else max(handed_ns, self._last_end)
        out = [start + k * self.byte_ns for k in range(n)]
        if n:
            self._last_end = out[-1] + self.byte_ns
        return out


__all__ = ["ByteTimes"]

"""A frame as one line of text, for the logs viewers show (rerun's text log, Foxglove's Log).

A run repeats the same frames between the same endpoints over and over (probes, MSG1, ACKs),
and the decoded view is a function of the bytes, so lines are made once per distinct
``(link, src, dst, kind, bytes)`` and cached.
"""

from __future__ import annotations

from bus.codec import Frame, Kind, Link
from bus.envelope import Envelope


def describe(env: Envelope) -> str:
    """The decoded frame (``ACK 11``, ``MCW 4 8 ...``), or its kind and bytes if it does not decode."""
    try:
        return Frame(Link(env.link), Kind(env.kind), env.raw, env.view).describe()
    except (KeyError, ValueError, TypeError):  # a view we cannot print: show the bytes
        return f"{env.kind or '?'} {env.raw.hex()}"


class FrameLines:
    """``src → dst  decoded  [hex]`` per frame, cached by what the line depends on."""

    def __init__(self) -> None:
        self._cache: dict[tuple[str, str, str, str, bytes], str] = {}

    def line(self, env: Envelope) -> str:
        key = (env.link, env.src, env.dst, env.kind, env.raw)
        text = self._cache.get(key)
        if text is None:
            text = self._cache[key] = f"{env.src} → {env.dst}  {describe(env)}  [{env.raw.hex()}]"
        return text

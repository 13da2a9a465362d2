"""Which of a recording's error events are errors, and which are a healthy run's expected noise.

A HexBot fleet makes some "errors" by design; counting them as failures would hide the real
ones (a run that reached its goal reported hundreds). Each expected kind has a reason:

* ``boot-handshake``: UART0 overruns of the byte ``'R'`` during the boot handshake (the control
  board repeats 'R' while the comm board blinks its LEDs and does not read).
* ``boot-banners``: collisions before the PC's first command: every comm board announces itself
  on its centre transceiver at power-up, all at once.
* ``all-answer``: collisions and noise at the PC while every module answers every command: at
  boot, in v1 behaviour until the first ``Select`` has been answered (docs/protocol.md), and
  always in the thesis-2009 profile, which has no addressing.
* ``side-light``: UART1 overruns of bytes that came through a side transceiver: neighbours
  repeat their localization messages (MSG1, six times) and replies reach whichever side the
  multiplexer selects, while a busy comm board is not reading.

Everything else is an error: noise and collisions once the PC talks (data lost), overruns on the
centre channel (a PC command lost), timeouts, bad samples, recorder errors.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from bus.functions import FunctionCode

from .reader import iter_samples

WHY = {
    "boot-handshake": "UART0 overruns of 'R' in the boot handshake: the control board repeats it "
                      "while the comm board blinks its LEDs",
    "boot-banners": "collisions before the PC's first command: every comm board announces itself "
                    "at power-up, all at once",
    "all-answer": "collisions and noise at the PC while every module answers every command (boot "
                  "banners; v1 behaviour until the first Select is answered; the thesis profile)",
    "side-light": "UART1 overruns from a side transceiver: neighbours repeat localization messages "
                  "and replies reach the selected side while the comm board is busy",
}
_HANDSHAKE_BYTE = 0x52  # 'R'
_SELECT = int(FunctionCode.Select)


@dataclass
class Health:
    """Error events split into real errors (by kind) and expected ones (by reason, see :data:`WHY`)."""

    errors: Counter[str] = field(default_factory=Counter)
    expected: Counter[str] = field(default_factory=Counter)

    def to_dict(self) -> dict[str, Any]:
        return {"errors": dict(sorted(self.errors.items())), "expected": dict(sorted(self.expected.items()))}


@dataclass(frozen=True)
class PcTimeline:
    """What the PC said when: its first command, and when modules stopped all answering
    (the first command after the first ``Select``; None: they never did)."""

    first_command_ns: int | None = None
    all_answer_until_ns: int | None = None


def reason(event: dict[str, Any], pc: PcTimeline) -> str | None:
    """The reason an error event is expected (a key of :data:`WHY`), or None: it is an error."""
    kind = event.get("kind")
    t = event.get("sim_time_ns")
    if not isinstance(t, int):
        t = None
    at_pc = event.get("receiver") == "pc" if kind == "collision" else event.get("src") == "pc"
    if kind in ("collision", "rx-noise") and at_pc and t is not None and (
            pc.all_answer_until_ns is None or t <= pc.all_answer_until_ns):  # noise ends when the PC talks again
        return "all-answer"
    if kind == "uart-overrun":
        if event.get("uart") == "uart0" and event.get("lost") == _HANDSHAKE_BYTE:
            return "boot-handshake"
        channel = event.get("channel")
        if event.get("uart") == "uart1" and isinstance(channel, int) and channel != 0:
            return "side-light"
    elif kind == "collision" and t is not None and (pc.first_command_ns is None or t < pc.first_command_ns):
        return "boot-banners"
    return None


def classify(events: Iterable[dict[str, Any]], pc: PcTimeline) -> Health:
    """Split ``event/*`` payloads (decoded) given what the PC said when."""
    out = Health()
    for ev in events:
        why = reason(ev, pc)
        if why is None:
            out.errors[str(ev.get("kind", "?"))] += 1
        else:
            out.expected[why] += 1
    return out


def health(path: str | Path, topics: Iterable[str]) -> Health:
    """The split for a recording; ``topics`` its channels (``event/*`` and ``frame/pc/*`` are read).

    Events that are not JSON objects count as errors of kind ``?``; recorder errors (topic
    ``_recorder/error``) as ``recorder:<reason>``."""
    topics = list(topics)
    starts: list[tuple[int, bool]] = []  # (first byte, is a Select) of every PC command
    for s in iter_samples(path, [t for t in topics if t.startswith("frame/pc/")]):
        try:
            d = json.loads(s.data)
            t = d.get("first_byte_ns", d.get("sim_time_ns"))
            raw = bytes.fromhex(d.get("raw", ""))
        except (ValueError, AttributeError, TypeError):
            continue
        if isinstance(t, int):
            starts.append((t, len(raw) > 1 and raw[1] == _SELECT))
    starts.sort()
    first_select = next((i for i, (_, sel) in enumerate(starts) if sel), None)
    pc = PcTimeline(starts[0][0] if starts else None,
                    None if first_select is None else
                    starts[first_select + 1][0] if first_select + 1 < len(starts) else 2**63)
    events: list[dict[str, Any]] = []
    out = Health()
    for s in iter_samples(path, [t for t in topics if t.startswith("event/") or t == "_recorder/error"]):
        try:
            ev = json.loads(s.data)
        except ValueError:
            ev = None
        if s.topic == "_recorder/error":
            out.errors["recorder:" + str(ev.get("reason", "?") if isinstance(ev, dict) else "?")] += 1
        elif isinstance(ev, dict):
            events.append(ev)
        else:
            out.errors["?"] += 1
    split = classify(events, pc)
    out.errors.update(split.errors)
    out.expected.update(split.expected)
    return out

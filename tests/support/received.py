"""What every IR receiver of a recorded run decoded, from its ``ir/rx`` samples: each burst's
bytes with every ``garble`` correction and ``cut`` applied, then :class:`bus.ir.IrReceiver`'s
rule for one UART line (of two garbled bytes that overlap, only the first to complete forms a
byte), byte by byte at each stop bit. The IR medium's lookahead contract (docs/bus.md, Shards)
is that a correction reaches a receiver before its byte's stop bit, so these are the bytes
the receiver delivered; one that came later is an ``ir-conflict`` event of the receiver (the
tests require none), since the receiver had delivered the byte before it. The order of the samples is not used: over shards, light from another
process is handled a window late, and the recorder logs an ``ir/rx`` sample (it has no time of
its own) at the last sim time it saw."""

from __future__ import annotations

import json
from pathlib import Path

from recordings.reader import iter_samples

Byte = tuple[int, int, int, int, bool]  # stop bit (ns), transceiver, value, start (ns), garbled


def received(path: str | Path) -> dict[str, list[Byte]]:
    """Every receiver (``ir/rx/<dst>``'s ``dst``) and the bytes it delivered, in order."""
    bursts: dict[str, dict[tuple[str, int], list[list]]] = {}
    for s in iter_samples(path):
        if not s.topic.startswith("ir/rx/"):
            continue
        mine = bursts.setdefault(s.topic[len("ir/rx/"):], {})
        d = json.loads(s.data)
        kind = d.get("type")
        if kind == "garble":
            for src, burst, i, v in d["fixes"]:
                entries = mine.get((src, burst))
                if entries and i < len(entries):
                    entries[i][2], entries[i][4] = v, True
        elif kind == "cut":
            entries = mine.get((d["src"], d["burst"]))
            if entries:
                i = d["index"]
                if d.get("value") is not None and i < len(entries):
                    entries[i][2], entries[i][4] = d["value"], True
                    i += 1
                del entries[i:]
        else:
            corrupt = d["corrupt"] or [False] * len(d["starts"])
            mine[(d["src"], d["burst"])] = [[start + d["byte_ns"], d["rx_transceiver"], v, start, bad]
                                            for start, v, bad in zip(d["starts"], bytes.fromhex(d["data"]),
                                                                     corrupt)]
    return {dst: _delivered(mine) for dst, mine in sorted(bursts.items())}


def _delivered(bursts: dict[tuple[str, int], list[list]]) -> list[Byte]:
    out: list[Byte] = []
    busy: dict[int, int] = {}
    for end, k, v, start, bad in sorted(tuple(e) for entries in bursts.values() for e in entries):
        if bad and start < busy.get(k, -1):
            continue  # one line: the garbled byte that completed first carried the mixture
        busy[k] = end
        out.append((end, k, v, start, bad))
    return out


def pc_noise(path: str | Path) -> list[dict]:
    """What the PC's framer made no frame of (``rx-noise`` on ``event/pc``), in order: bytes
    the PC itself decoded, live."""
    return [d for s in iter_samples(path, ["event/pc"]) if (d := json.loads(s.data)).get("kind") == "rx-noise"]

"""Records read by their shape: a bus record as hexbench writes it is a few fields, its time,
the rest — ``{"module":"m3","sim_time_ns":123,"joints_open":[...],...}`` — and the bytes on
either side of the time repeat all run long (a module's head; an actuator record's tail depends
on its ports alone). :class:`RecordShapes` decodes each side once and keeps it, so a record
costs a lookup and a dict merge instead of a JSON decode.

Exact, not a guess: :meth:`RecordShapes.decode` gives what ``json`` gives for the whole payload
(the same dict: keys in the same order, a repeated key's last value) or None (decode it).
A head ``H`` is kept only if ``H + "0}"`` and ``H + "1}"`` decode to objects that differ in
nothing but a top-level ``sim_time_ns`` of 0 and 1 (then the number after ``H`` is that
field's value, whatever it is); a tail ``T`` only if it is ``}`` or ``,`` + the members of a
non-empty object (``"{" + T[1:]`` decodes); the time between them is ``0`` or digits without a
leading zero, followed at once by the tail; neither side holds a NaN or an infinity. Both sides split the payload at ASCII bytes, so it
is valid UTF-8 exactly when both are. The values kept are shared by the dicts returned: read
them, do not change them.
"""

from __future__ import annotations

import json
import re
from typing import Any



def _no_constant(name: str) -> Any:
    raise ValueError(name)


#: NaN and the infinities are not kept: a NaN is unequal to a fresh one, but equal to itself,
#: so a value shared by many records would compare unlike the fresh values ``json`` makes
_decode = json.JSONDecoder(parse_constant=_no_constant).decode
_TIME = b'"sim_time_ns":'
_DIGITS = re.compile(rb"(0|[1-9][0-9]{0,18})[,}]")
_MISS = object()
#: a side longer than this is decoded each time, not kept (a collision event's list of sources)
MAX_KEPT = 1024
#: sides kept per cache; then it starts over
MAX_SIDES = 16384


def _object(text: bytes) -> dict[str, Any] | None:
    try:
        obj = _decode(text.decode("utf-8"))
    except ValueError:  # UnicodeDecodeError is a ValueError
        return None
    return obj if isinstance(obj, dict) else None


def _head(head: bytes) -> dict[str, Any] | None:
    """The fields before the time, the time 0 in its place; None if the number after ``head``
    is not a top-level ``sim_time_ns`` (or ``head`` no object's start)."""
    zero, one = _object(head + b"0}"), _object(head + b"1}")
    if zero is None or one is None:
        return None
    t0, t1 = zero.get("sim_time_ns"), one.get("sim_time_ns")
    if type(t0) is not int or t0 != 0 or type(t1) is not int or t1 != 1 or {**zero, "sim_time_ns": 1} != one:
        return None
    return zero


def _tail(tail: bytes) -> dict[str, Any] | None:
    """The fields after the time; None if ``tail`` is not ``}`` or ``,`` + an object's members."""
    if tail == b"}":
        return {}
    if tail[:1] != b",":
        return None
    obj = _object(b"{" + tail[1:])
    return obj if obj else None  # "{}" would be a trailing comma in the whole


class RecordShapes:
    """Heads and tails of records seen, decoded (a recorder's: not thread-safe)."""

    def __init__(self) -> None:
        self._heads: dict[bytes, dict[str, Any] | None] = {}
        self._tails: dict[bytes, dict[str, Any] | None] = {}

    def decode(self, payload: bytes) -> dict[str, Any] | None:
        """``json.loads(payload)`` if the payload is an object with an integer ``sim_time_ns``
        whose sides are known or can be; else None (decode it yourself: it may not be JSON)."""
        i = payload.find(_TIME)
        if i < 0:
            return None
        j = i + len(_TIME)
        m = _DIGITS.match(payload, j)
        if m is None:
            return None
        k = m.end(1)
        head, tail = payload[:j], payload[k:]
        h = self._heads.get(head, _MISS)
        if h is _MISS:
            h = self._keep(self._heads, head, _head(head))
        if h is None:
            return None
        t = self._tails.get(tail, _MISS)
        if t is _MISS:
            t = self._keep(self._tails, tail, _tail(tail))
        if t is None:
            return None
        obj = h.copy()
        obj["sim_time_ns"] = int(m.group(1))
        if t:
            obj.update(t)  # a key on both sides: its place from the head, its value from the tail, as json
        return obj

    @staticmethod
    def _keep(cache: dict[bytes, Any], side: bytes, value: Any) -> Any:
        if len(side) <= MAX_KEPT:
            if len(cache) >= MAX_SIDES:
                cache.clear()
            cache[side] = value
        return value

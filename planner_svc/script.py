"""``script:<file>``: one PC action per line, the modern form of the VB GUI's message box.

::

    # comments and blank lines are ignored
    select 3                  # v2 Select(1, 3): the next frames are for module 3
    send MCW 4 8 4 9          # a frame by function name (or code: send 21 4 8 4 9)
    expect ack 21             # wait (run time, 5 s default) for an ACK with byte 21
    expect banner banner=COMM_LST timeout=10
    wait 1.5                  # let 1.5 s of run time pass

``expect <kind> [value] [field=value ...] [timeout=<s>]``: kinds are the codec's frame
kinds (``ack``, ``banner``, ``position``, ...); a bare value after ``ack`` is the byte.
A bad line raises :class:`ScriptError` naming the file and line before anything is sent.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from bus.codec import Kind
from bus.errors import HexbenchError
from bus.functions import lookup
from bus.timing import NS_PER_S

from .bringup import BringUp
from .endpoint import ExpectTimeout, PcEndpoint

DEFAULT_TIMEOUT_S = 5.0


class ScriptError(HexbenchError, ValueError):
    """A script line that cannot be parsed or whose expectation failed."""


@dataclass(frozen=True)
class Action:
    line: int
    text: str
    verb: str
    args: tuple[str, ...]


def _int(v: str) -> int:
    return int(v, 0)


def _value(v: str) -> object:
    """A field value of ``expect``: integers (also 0x..), true/false, else the text."""
    if v.lower() in ("true", "false"):
        return v.lower() == "true"
    try:
        return int(v, 0)
    except ValueError:
        return v


def parse_script(text: str, source: str = "<script>") -> list[Action]:
    out: list[Action] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        verb, *args = line.split()
        where = f"{source}:{n}: {line!r}"
        try:
            if verb == "send":
                if not args:
                    raise ValueError("send needs a function name or code")
                fn = lookup(args[0])
                vals = [_int(a) for a in args[1:]]
                if len(vals) > len(fn.args):
                    raise ValueError(f"{fn.name} takes {len(fn.args)} arguments, got {len(vals)}")
            elif verb == "select":
                if len(args) != 1:
                    raise ValueError("select needs one module id")
                _int(args[0])
            elif verb == "wait":
                if len(args) != 1 or float(args[0]) < 0:
                    raise ValueError("wait needs one non-negative number of seconds")
            elif verb == "expect":
                if not args:
                    raise ValueError("expect needs a frame kind, e.g. 'expect ack 21'")
                Kind(args[0])
                for a in args[1:]:
                    if "=" not in a and not (args[0] == "ack" and a == args[1]):
                        raise ValueError(f"expect takes field=value pairs, got {a!r}")
            else:
                raise ValueError(f"unknown action {verb!r}; actions: send, select, wait, expect")
        except (ValueError, KeyError) as exc:
            raise ScriptError(f"{where}: {exc.args[0] if exc.args else exc}") from None
        out.append(Action(n, line, verb, tuple(args)))
    return out


def run_script(path: str, pc: PcEndpoint, bringup: BringUp, *,
               say: Callable[[str], None] = print) -> int:
    """Run a script file; returns the number of actions. Raises :class:`ScriptError`."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ScriptError(f"script {path!r}: {exc.strerror}") from None
    actions = parse_script(text, str(p))
    clock = pc.bus.clock
    mark = len(pc.received)
    for a in actions:
        say(f"script {p.name}:{a.line}: {a.text}")
        if a.verb == "send":
            mark = len(pc.received)
            pc.send(lookup(a.args[0]).code, *[_int(v) for v in a.args[1:]])
        elif a.verb == "select":
            bringup.select(_int(a.args[0]))
            mark = len(pc.received)
        elif a.verb == "wait":
            end = clock.now_ns() + int(float(a.args[0]) * NS_PER_S)
            clock.run(until_ns=end, until=lambda: clock.now_ns() >= end)
        else:
            kind, rest = a.args[0], list(a.args[1:])
            fields: dict[str, object] = {}
            timeout = DEFAULT_TIMEOUT_S
            if kind == "ack" and rest and "=" not in rest[0]:
                fields["byte"] = _int(rest.pop(0))
            for kv in rest:
                k, v = kv.split("=", 1)
                if k == "timeout":
                    timeout = float(v)
                else:
                    fields[k] = _value(v)
            try:
                r = pc.expect(kind, since=mark, timeout_s=timeout, **fields)
            except ExpectTimeout as exc:
                raise ScriptError(f"{p}:{a.line}: {a.text!r} failed: {exc}") from None
            mark = pc.received.index(r) + 1
    return len(actions)

"""The wire codec: build and parse every HexBot frame (spec §5, §6, §9, §13).

Each link kind has a grammar: a list of :class:`Template` (fixed head, a number
of free bytes, fixed tail). :func:`parse` decodes one complete frame; the
streaming :class:`bus.framer.Framer` uses the same templates, so the grammar is
written once. Raw bytes are always kept in :attr:`Frame.raw`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Iterable

from .functions import ARG_UNUSED, FUNCTIONS, Function, WalterFlag, WalterOp, lookup

PREAMBLE = b"\n\r\n\r"
EOL = b"\n\r"
ROLE_PREFIX = {"S": b"S: ", "M": b"M: "}
START = b"*"
END = b"#"
HANDSHAKE_READY = b"R"
HANDSHAKE_LISTENING = b"L"
#: The two bytes ``LCircle`` sends on every side (a probe of the IR link).
PROBE_BYTES = (0xFF, 0x00)

#: Banner texts, by the firmware routine that prints them.
BANNERS: dict[str, bytes] = {
    "CTR_Ready": b"CTR. BOARD READY",
    "COMM_Ready": b"COMM. BOARD READY",
    "CTR_LST": b"CTR. LISTENING",
    "COMM_LST": b"COMM. LISTENING",
    "LOC": b"LOCALIZED",
    "RCV": b"RECEIVED",
}
PC_FRAME_LEN = 11
RELAY_FRAME_LEN = 7
MSG1_LEN = 8
#: v2 location report body: "POS" id x+128 y+128 yref flags.
POS_TAG = b"POS"
#: v2 actuator report on the debug UART: "ACT" joints magnets+ magnets- (bit k-1 = J k / S k).
ACT_TAG = b"ACT"
#: Coils the on-time limit switched off (debug UART, both profiles), bits as in ACT.
LIM_TAG = b"LIM"
#: v2 SelfTest summary on the debug UART: "TST" id switches (bit k-1 = a neighbour on side k).
TST_TAG = b"TST"
#: v2 version report on the centre channel: "VER" major minor profile.
VER_TAG = b"VER"
#: What our programs report to ``Version``: the protocol release (docs/protocol.md) and the
#: profile byte (2 = v2; a thesis-2009 module does not know the code and answers 'N').
#: 2.2: MSG1's tens byte up to 12 (v2 carries -127..127), id 0 never an address, a frame's bytes
#: within FRAME_BYTE_TICKS of each other, Walter's rounds (WalterSetup/Goal/Beat, STwo, WalterLog).
FIRMWARE_VERSION = (2, 2)
PROFILE_V2 = 2
#: What an image prints on its UART1, about once a second, when the EEPROM's board-kind record
#: (bus.chip) does not name the board it was built for: it drives no pin then.
GUARD_TEXTS: dict[tuple[str, str], bytes] = {
    ("comm", "control"): b"WRONG BOARD: COMM IMAGE, EEPROM SAYS CONTROL",
    ("control", "comm"): b"WRONG BOARD: CONTROL IMAGE, EEPROM SAYS COMM",
    ("comm", "none"): b"UNKNOWN BOARD: COMM IMAGE, NO BOARD RECORD IN EEPROM",
    ("control", "none"): b"UNKNOWN BOARD: CONTROL IMAGE, NO BOARD RECORD IN EEPROM",
}
#: POS and Select mode 2 carry a coordinate as x + 128 in one byte.
COORD_OFFSET = 128
#: The coordinates the protocol carries, relative to the reference (the fixed module after
#: ``Ref``), per profile: the thesis's MSG1 has two decimal digits (-99..99); v2's MSG1 carries
#: |x| div 10 in the tens byte (0..12) so that it reaches what POS's x + 128 byte carries
#: (-127..127, symmetric). Scenarios, plans and both programs are held to it.
COORD_LIMIT = {"v2": 127, "thesis-2009": 99}
#: v2 Walter rounds (docs/protocol.md): a mover's request and a neighbour's answer on the side
#: link (tag, op, complement of op), the round's debug line, the busy byte on the centre channel.
WALTER_REQUEST_TAG = b"W"
WALTER_ANSWER_TAG = b"w"
WALTER_LOG_TAG = b"WLK"
WALTER_BUSY = b"W"
WALTER_NO_POSITION = 255
WALTER_REQUEST_LEN = 4
WALTER_ANSWER_LEN = 3
#: Goal table entries a module holds (positions 0..63), three bytes each of the comm board's
#: RAM (docs/firmware.md); entries beyond are not kept. The C table is this size (hexbot_gen.h).
WALTER_TABLE_CAPACITY = 64
#: The largest Walter problem a module holds: an entry per position but the anchor's. The PC
#: refuses a larger one before the fleet boots (planner_svc.rounds.beyond_the_modules).
WALTER_MAX_MODULES = WALTER_TABLE_CAPACITY + 1


class Link(str, Enum):
    """Kinds of wire. Each has one grammar (and one framer)."""

    PC = "pc"  # centre IR, PC -> modules: 11-byte command frames
    CENTRE = "centre"  # centre IR, modules -> PC: banners, ACKs, reports
    SIDE = "side"  # side IR between neighbours: MSG1, LCircle probes
    UART0_DOWN = "uart0-down"  # comm -> control: 7-byte relay frames, handshake
    UART0_UP = "uart0-up"  # control -> comm: handshake, code echo
    DEBUG = "debug"  # control UART1 -> PC terminal


class Kind(str, Enum):
    COMMAND = "command"
    RELAY = "relay"
    ECHO = "echo"
    HANDSHAKE = "handshake"
    BANNER = "banner"
    ACK = "ack"
    DEBUG_MSG = "debug-msg"
    ACTUATORS = "actuators"
    SIDE_REPORT = "side-report"
    YREF_REPORT = "yref-report"
    POSITION = "position"
    VERSION = "version"
    COIL_LIMIT = "coil-limit"
    SELF_TEST = "self-test"
    BOARD_GUARD = "board-guard"
    MSG1 = "msg1"
    WALTER_REQUEST = "walter-request"
    WALTER_ANSWER = "walter-answer"
    WALTER_LOG = "walter-log"
    WALTER_BUSY = "walter-busy"
    PROBE = "probe"
    NOISE = "noise"


@dataclass(frozen=True)
class Template:
    """A frame shape: ``head`` bytes, ``n_any`` free bytes, ``tail`` bytes."""

    kind: Kind
    head: bytes
    n_any: int = 0
    tail: bytes = b""
    label: str = ""  # e.g. the banner name

    @property
    def length(self) -> int:
        return len(self.head) + self.n_any + len(self.tail)


def _prefixes(role_allowed: bool = True) -> list[bytes]:
    roles = [b"", ROLE_PREFIX["S"], ROLE_PREFIX["M"], ROLE_PREFIX["S"] + ROLE_PREFIX["M"]]
    return [pre + r for pre in (b"", PREAMBLE) for r in (roles if role_allowed else [b""])]


def _grammar(link: Link) -> tuple[Template, ...]:
    t: list[Template] = []
    if link is Link.PC:
        t.append(Template(Kind.COMMAND, START, PC_FRAME_LEN - 2, END))
    elif link is Link.UART0_DOWN:
        t.append(Template(Kind.RELAY, START, RELAY_FRAME_LEN - 2, END))
        t.append(Template(Kind.HANDSHAKE, HANDSHAKE_READY))
    elif link is Link.UART0_UP:
        t.append(Template(Kind.HANDSHAKE, HANDSHAKE_READY))
        t.append(Template(Kind.HANDSHAKE, HANDSHAKE_LISTENING))
        t.append(Template(Kind.ECHO, b"", 1))  # any other byte echoes a code
    elif link is Link.CENTRE:
        for p in _prefixes():
            for name, text in BANNERS.items():
                t.append(Template(Kind.BANNER, p + text + EOL, label=name))
            t.append(Template(Kind.ACK, p + b"ACK", 1, EOL))
            t.append(Template(Kind.POSITION, p + POS_TAG, 5, EOL))
            t.append(Template(Kind.VERSION, p + VER_TAG, 3, EOL))
        t.extend(_guard_templates())
        t.append(Template(Kind.SIDE_REPORT, b"Side: ", 1, EOL))
        t.append(Template(Kind.YREF_REPORT, b"Yref: ", 1, EOL))
        t.append(Template(Kind.WALTER_BUSY, WALTER_BUSY))
    elif link is Link.SIDE:
        for p in _prefixes():
            t.append(Template(Kind.MSG1, p + START, MSG1_LEN - 1))
        t.extend(Template(Kind.PROBE, bytes([b])) for b in PROBE_BYTES)
        t.append(Template(Kind.WALTER_REQUEST, WALTER_REQUEST_TAG, WALTER_REQUEST_LEN - 1))
        t.append(Template(Kind.WALTER_ANSWER, WALTER_ANSWER_TAG, WALTER_ANSWER_LEN - 1))
    elif link is Link.DEBUG:
        for p in _prefixes(role_allowed=False):
            for name in ("CTR_Ready", "COMM_Ready", "CTR_LST"):
                t.append(Template(Kind.BANNER, p + BANNERS[name] + EOL, label=name))
            t.append(Template(Kind.ACK, p + b"ACK", 1, EOL))
        t.append(Template(Kind.DEBUG_MSG, b"MSG", 5, EOL))
        t.append(Template(Kind.ACTUATORS, ACT_TAG, 3, EOL))
        t.append(Template(Kind.COIL_LIMIT, LIM_TAG, 3, EOL))
        t.append(Template(Kind.SELF_TEST, TST_TAG, 2, EOL))
        t.append(Template(Kind.WALTER_LOG, WALTER_LOG_TAG, 4, EOL))
        t.extend(_guard_templates())
    return tuple(t)


def _guard_templates() -> list[Template]:
    return [Template(Kind.BOARD_GUARD, PREAMBLE + text + EOL, label=f"{image}-on-{found}")
            for (image, found), text in GUARD_TEXTS.items()]


GRAMMARS: dict[Link, tuple[Template, ...]] = {link: _grammar(link) for link in Link}


@dataclass(frozen=True)
class Frame:
    """One frame as found on a link: its raw bytes and a decoded view."""

    link: Link
    kind: Kind
    raw: bytes
    view: dict[str, Any] = field(default_factory=dict)

    @property
    def is_noise(self) -> bool:
        return self.kind is Kind.NOISE

    def describe(self) -> str:
        """One line for people: ``command MCW i=4 t1=8 t2=4 t3=9``."""
        v = self.view
        if self.kind in (Kind.COMMAND, Kind.RELAY):
            args = " ".join(f"{k}={a}" for k, a in v["args"].items())
            return f"{self.kind.value} {v['name']} {args}".rstrip()
        if self.kind is Kind.NOISE:
            return f"noise {self.raw.hex()} ({v['reason']})"
        extras = " ".join(f"{k}={_show(a)}" for k, a in v.items())
        return f"{self.kind.value} {extras}".rstrip()


def _show(a: Any) -> str:
    return repr(a) if isinstance(a, str) else str(a)


def _prefix_view(raw: bytes) -> tuple[dict[str, Any], int]:
    """Parse the optional preamble and role prefix at the start of ``raw``."""
    view: dict[str, Any] = {"preamble": raw.startswith(PREAMBLE)}
    i = len(PREAMBLE) if view["preamble"] else 0
    role = ""
    for r, text in ROLE_PREFIX.items():
        if raw.startswith(text, i):
            role += r
            i += len(text)
    view["role"] = role or None
    return view, i


def decode_ack_byte(b: int) -> str:
    if b == ord("N"):
        return "unknown code"
    if b == ord("~"):
        return "no echo (timeout)"
    return FUNCTIONS[b].name


def _view(link: Link, tpl: Template, raw: bytes) -> dict[str, Any]:
    k = tpl.kind
    if k is Kind.COMMAND:
        fn = FUNCTIONS[raw[1]]
        return _args_view(fn, raw[2:10])
    if k is Kind.RELAY:
        fn = FUNCTIONS[raw[1]]
        return _args_view(fn, raw[2:6], filler=ARG_UNUSED)
    if k is Kind.ECHO:
        return {"code": raw[0], "name": FUNCTIONS[raw[0]].name}
    if k is Kind.HANDSHAKE:
        return {"signal": chr(raw[0])}
    if k is Kind.PROBE:
        return {"byte": raw[0]}
    if k in (Kind.WALTER_REQUEST, Kind.WALTER_ANSWER):
        return walter_side_view(raw)
    if k is Kind.WALTER_BUSY:
        return {}
    if k is Kind.WALTER_LOG:
        return walter_log_view(raw[3:7])
    view, i = _prefix_view(raw)
    if k is Kind.BOARD_GUARD:
        image, found = tpl.label.split("-on-")
        return {"image": image, "eeprom": found, "text": raw[len(PREAMBLE):-len(EOL)].decode("ascii")}
    if k is Kind.BANNER:
        view["banner"] = tpl.label
        view["text"] = raw[i:-len(EOL)].decode("ascii")
    elif k is Kind.ACK:
        b = raw[i + 3]
        view["byte"] = b
        view["meaning"] = decode_ack_byte(b)
    elif k is Kind.DEBUG_MSG:
        body = raw[3:8]
        view.update(_args_view(FUNCTIONS[body[0]], body[1:], filler=ARG_UNUSED))
    elif k in (Kind.ACTUATORS, Kind.COIL_LIMIT):
        view.update(actuator_report_view(raw[3:6]))
    elif k is Kind.SELF_TEST:
        view.update(id=raw[3], switches=[bool(raw[4] >> s & 1) for s in range(6)])
    elif k is Kind.VERSION:
        major, minor, prof = raw[i + 3:i + 6]
        view.update(version=f"{major}.{minor}", profile="v2" if prof == PROFILE_V2 else f"unknown ({prof})")
    elif k in (Kind.SIDE_REPORT, Kind.YREF_REPORT):
        b = raw[6]
        view["byte"] = b
        view["value"] = b - ord("0")
    elif k is Kind.POSITION:
        ident, x, y, yref, flags = raw[i + 3:i + 8]
        view.update(id=ident, x=x - COORD_OFFSET, y=y - COORD_OFFSET, yref=yref,
                    localized=bool(flags & 1), mobile=bool(flags & 2), substrate=bool(flags & 4))
    elif k is Kind.MSG1:
        view.update(msg1_view(raw[i:]))
    return view


def _args_view(fn: Function, data: bytes, filler: int | None = None) -> dict[str, Any]:
    args = {a.name: data[n] for n, a in enumerate(fn.args) if n < len(data)}
    extra = list(data[len(fn.args):])
    view: dict[str, Any] = {"code": fn.code, "name": fn.name, "args": args}
    if any(b not in (0, filler) for b in extra):
        view["extra"] = extra
    return view


# --- parse -----------------------------------------------------------------------------
class Match(Enum):
    FAIL = 0
    NEED = 1
    OK = 2


def match(tpl: Template, buf: bytes | bytearray, start: int = 0) -> tuple[Match, int]:
    """Match a template at ``buf[start:]``: (OK, length) / (NEED, bytes known good) / (FAIL, index of mismatch)."""
    n = len(buf) - start
    h = len(tpl.head)
    if n < h:
        return (Match.NEED, n) if buf[start:] == tpl.head[:n] else (Match.FAIL, _mismatch(buf, start, tpl.head))
    if buf[start:start + h] != tpl.head:
        return Match.FAIL, _mismatch(buf, start, tpl.head)
    tail_at = h + tpl.n_any
    have = n - tail_at
    if have < len(tpl.tail):
        ok = have <= 0 or buf[start + tail_at:] == tpl.tail[:have]
        return (Match.NEED, n) if ok else (Match.FAIL, tail_at + _mismatch(buf, start + tail_at, tpl.tail))
    if buf[start + tail_at:start + tpl.length] != tpl.tail:
        return Match.FAIL, tail_at + _mismatch(buf, start + tail_at, tpl.tail)
    return Match.OK, tpl.length


def _mismatch(buf: bytes | bytearray, start: int, expect: bytes) -> int:
    for k, e in enumerate(expect):
        if start + k >= len(buf) or buf[start + k] != e:
            return k
    return len(expect)


def parse(link: Link | str, raw: bytes) -> Frame:
    """Decode ``raw`` as exactly one frame of ``link``; anything else is a noise frame."""
    link = Link(link)
    best: Template | None = None
    for tpl in GRAMMARS[link]:
        m, n = match(tpl, raw)
        if m is Match.OK and n == len(raw) and (best is None or tpl.length > best.length):
            best = tpl
    if best is None:
        return noise(link, raw, explain(link, raw))
    return Frame(link, best.kind, bytes(raw), _view(link, best, bytes(raw)))


def frame_from_template(link: Link, tpl: Template, raw: bytes) -> Frame:
    return Frame(link, tpl.kind, bytes(raw), _view(link, tpl, bytes(raw)))


def noise(link: Link, raw: bytes, reason: str) -> Frame:
    return Frame(link, Kind.NOISE, bytes(raw), {"reason": reason})


def explain(link: Link, raw: bytes | bytearray) -> str:
    """Why ``raw`` is not a frame of ``link``: the closest template and where it broke."""
    best_k, best = -1, None
    for tpl in GRAMMARS[link]:
        m, k = match(tpl, raw)
        if m is Match.OK:
            k = tpl.length
        if k > best_k:
            best_k, best = k, tpl
    if not raw:
        return "empty"
    if best is None or best_k <= 0:
        return f"byte 0x{raw[0]:02x} does not start a {link.value} frame"
    if best_k >= best.length:
        return f"{len(raw) - best.length} bytes after a complete {best.kind.value} frame"
    if best_k >= len(raw):
        return f"truncated {best.kind.value} frame ({len(raw)} of {best.length} bytes)"
    pos = best_k
    exp = (best.head + bytes(best.n_any) + best.tail)[pos]
    where = "end" if pos >= len(best.head) + best.n_any else "byte"
    return (f"{best.kind.value} frame: expected 0x{exp:02x} {where} at offset {pos}, "
            f"got 0x{raw[pos]:02x}")


# --- build -----------------------------------------------------------------------------
def _arg_bytes(fn: Function, args: Iterable[int] | dict[str, int], width: int, filler: int) -> bytes:
    # Only an argument left out (a keyword not given) is the filler unchecked: a given value
    # equal to the filler (0 in a PC frame, 'N' in a relay) is checked like any other.
    if isinstance(args, dict):
        unknown = set(args) - set(fn.arg_names)
        if unknown:
            raise ValueError(f"{fn.name} has no argument {sorted(unknown)}; it takes {fn.arg_names}")
        vals = [args.get(a.name, filler) for a in fn.args]
        given = [(a, args[a.name]) for a in fn.args if a.name in args]
    else:
        vals = list(args)
        given = list(zip(fn.args, vals))
    if len(vals) > width:
        raise ValueError(f"{fn.name}: {len(vals)} arguments do not fit {width} bytes")
    for a, v in given:
        a.check(v)
    for v in vals:
        if not 0 <= v <= 255:
            raise ValueError(f"argument {v} is not a byte")
    return bytes(vals) + bytes([filler]) * (width - len(vals))


def encode_command(fn: str | int | Function, *args: int, **kwargs: int) -> bytes:
    """PC -> module frame (Table 3-8): ``'*' B1..B9 '#'``; unused bytes are 0."""
    f = fn if isinstance(fn, Function) else lookup(fn)
    body = _arg_bytes(f, kwargs if kwargs else args, 8, 0)
    return START + bytes([f.code]) + body + END


def encode_relay(code: int | Function, *args: int) -> bytes:
    """Comm -> control frame over UART0: ``'*' code a b c d '#'``, unused = 'N'."""
    f = code if isinstance(code, Function) else FUNCTIONS[code]
    return START + bytes([f.code]) + _arg_bytes(f, args, 4, ARG_UNUSED) + END


def role_prefix(mobile: bool, substrate: bool) -> bytes:
    """The comm board's role prefix: "S: " if S=1, then "M: " if M=1."""
    return (ROLE_PREFIX["S"] if substrate else b"") + (ROLE_PREFIX["M"] if mobile else b"")


def encode_banner(name: str, *, preamble: bool = False, role: bytes = b"") -> bytes:
    return (PREAMBLE if preamble else b"") + role + BANNERS[name] + EOL


def encode_ack(byte: int, *, role: bytes = b"", preamble: bool = True) -> bytes:
    """Module -> PC acknowledgement: preamble, role, ``"ACK"`` and one byte."""
    return (PREAMBLE if preamble else b"") + role + b"ACK" + bytes([byte]) + EOL


def encode_debug_msg(relay_body: bytes) -> bytes:
    """Control board's debug ``MSG`` line: the five bytes after '*' of a relay frame."""
    if len(relay_body) != 5:
        raise ValueError("a relay body is 5 bytes: code a b c d")
    return b"MSG" + bytes(relay_body) + EOL


def _mask(bits: Iterable[bool]) -> int:
    return sum(1 << k for k, on in enumerate(bits) if on)


def encode_actuator_report(joints_open: Iterable[bool], magnets: Iterable[int]) -> bytes:
    """v2 control board's debug ``ACT`` line: which solenoids are energised (J1..J6) and which
    magnet relays are on (S1..S6, positive and negative), one bit each, ``0A 0D``.
    ``magnets`` as in :class:`bus.messages.Actuators`: +1, -1, 0, or 2 for both relays."""
    m = list(magnets)
    return (ACT_TAG + bytes([_mask(joints_open), _mask(v in (1, 2) for v in m),
                             _mask(v in (-1, 2) for v in m)]) + EOL)


def encode_coil_limit(joints: int, pos: int, neg: int) -> bytes:
    """Control board's debug ``LIM`` line: the coils the on-time limit just switched off."""
    return LIM_TAG + bytes([joints, pos, neg]) + EOL


def encode_self_test(ident: int, switches: int) -> bytes:
    """v2 control board's debug ``TST`` line: the DIP id it reads and the optical switches the
    comm board passed on (bit k-1 = a neighbour on side k)."""
    return TST_TAG + bytes([ident & 0xFF, switches & 0x3F]) + EOL


def encode_version(*, role: bytes = b"") -> bytes:
    """v2 comm board's answer to ``Version``: preamble, role, ``"VER"`` major minor profile."""
    return PREAMBLE + role + VER_TAG + bytes([*FIRMWARE_VERSION, PROFILE_V2]) + EOL


def actuator_report_view(body: bytes) -> dict[str, Any]:
    """Decode the three bytes after ``ACT``: ``joints_open`` and ``magnets`` (+1/-1/0/2)."""
    j, pos, neg = body[:3]
    magnets = []
    for k in range(6):
        p, n = pos >> k & 1, neg >> k & 1
        magnets.append(2 if p and n else 1 if p else -1 if n else 0)
    view: dict[str, Any] = {"joints_open": [bool(j >> k & 1) for k in range(6)], "magnets": magnets}
    if (j | pos | neg) >> 6:
        view["extra_bits"] = [j >> 6, pos >> 6, neg >> 6]
    return view


def encode_side_report(side: int) -> bytes:
    return b"Side: " + bytes([(side + ord("0")) & 0xFF]) + EOL


def encode_yref_report(yref: int) -> bytes:
    return b"Yref: " + bytes([(yref + ord("0")) & 0xFF]) + EOL


def msg1_digits(x: int, y: int, side: int) -> bytes:
    """MSG1 after '*': sign, tens, units of X; sign, tens, units of Y; side S.
    Sign bytes are 0 for non-negative and 1 for negative; the tens byte is |v| div 10 (v2:
    0..12), the units 0..9. A coordinate beyond ``COORD_LIMIT["v2"]`` is a ValueError: a
    program checks its cell before it sends (:func:`msg1_carries`)."""
    for v in (x, y):
        if not msg1_carries(v):
            raise ValueError(f"MSG1 carries coordinates in {coord_range('v2')}, not {v}")
    if not 1 <= side <= 6:
        raise ValueError(f"MSG1 side must be 1..6, not {side}")
    return bytes([int(x < 0), abs(x) // 10, abs(x) % 10, int(y < 0), abs(y) // 10, abs(y) % 10, side])


def msg1_carries(v: int) -> bool:
    """Whether a v2 MSG1 (and POS, Select mode 2) can carry coordinate ``v``."""
    return abs(v) <= COORD_LIMIT["v2"]


def coord_range(profile: str) -> str:
    """``"-127..127"``: the coordinates ``profile`` carries, as a message says it."""
    return f"-{COORD_LIMIT[profile]}..{COORD_LIMIT[profile]}"


def encode_msg1(x: int, y: int, side: int, *, role: bytes = b"", preamble: bool = True) -> bytes:
    return (PREAMBLE if preamble else b"") + role + START + msg1_digits(x, y, side)


def msg1_view(body: bytes) -> dict[str, Any]:
    """Decode the 8 bytes ``'*' sx x1 x0 sy y1 y0 S``."""
    sx, x1, x0, sy, y1, y0, s = body[1:8]
    x = (10 * x1 + x0) * (-1 if sx else 1)
    y = (10 * y1 + y0) * (-1 if sy else 1)
    sane = (x0 <= 9 and y0 <= 9 and sx in (0, 1) and sy in (0, 1) and 1 <= s <= 6
            and msg1_carries(x) and msg1_carries(y))
    return {"x": x, "y": y, "side": s, "valid": sane}


def encode_position(ident: int, x: int, y: int, yref: int, *, localized: bool, mobile: bool,
                    substrate: bool, role: bytes = b"") -> bytes:
    """v2 location report: preamble, role, ``"POS"`` id x+128 y+128 yref flags, EOL."""
    if not (msg1_carries(x) and msg1_carries(y)):
        raise ValueError(f"POS carries coordinates in {coord_range('v2')}, not ({x}, {y})")
    flags = int(localized) | int(mobile) << 1 | int(substrate) << 2
    return (PREAMBLE + role + POS_TAG
            + bytes([ident & 0xFF, x + COORD_OFFSET, y + COORD_OFFSET, yref % 6, flags])
            + EOL)


# --- v2 Walter rounds (docs/protocol.md) ---------------------------------------------------
def encode_walter_request(op: int, position: int) -> bytes:
    """A mover's request on the side link: what it asks, and its position (who passes)."""
    return WALTER_REQUEST_TAG + bytes([op, ~op & 0xFF, position & 0xFF])


def encode_walter_answer(op: int) -> bytes:
    """A neighbour's answer on the side link: the op it will do."""
    return WALTER_ANSWER_TAG + bytes([op, ~op & 0xFF])


def walter_side_op(body: bytes) -> int | None:
    """The op of the two bytes after a side message's tag, or None if they do not check."""
    op, check = body[0], body[1]
    return op if check == ~op & 0xFF and op in WalterOp._value2member_map_ else None


def walter_side_view(raw: bytes) -> dict[str, Any]:
    op = walter_side_op(raw[1:3])
    view: dict[str, Any] = {"op": WalterOp(op).name.lower() if op is not None else None,
                            "valid": op is not None}
    if raw[:1] == WALTER_REQUEST_TAG:
        view["position"] = raw[3]
    return view


#: A goal table entry's mode byte (``WalterGoal``): bit 0 CW, bits 1..4 the delay in rounds.
WALTER_MODE_CW = 1
WALTER_MODE_DELAY_SHIFT = 1
WALTER_MODE_DELAY_MAX = 15


def walter_mode(cw: bool, delay: int) -> int:
    if not 0 <= delay <= WALTER_MODE_DELAY_MAX:
        raise ValueError(f"a Walter delay is 0..{WALTER_MODE_DELAY_MAX} rounds, not {delay}")
    return int(cw) | delay << WALTER_MODE_DELAY_SHIFT


def walter_mode_view(mode: int) -> tuple[bool, int]:
    """(CW, delay) of a goal table entry's mode byte."""
    return bool(mode & WALTER_MODE_CW), mode >> WALTER_MODE_DELAY_SHIFT & WALTER_MODE_DELAY_MAX


def encode_walter_goals(entries: list[tuple[int, int, bool, int]]) -> list[bytes]:
    """``WalterGoal`` frames for a goal table in the module frame: entry k = (x, y, cw, delay)
    of position k, two a frame; x = y = -128 (0 on the wire) marks no entry."""
    frames = []
    for k in range(0, len(entries), 2):
        args = [k]
        for x, y, cw, delay in entries[k:k + 2]:
            args += [x + COORD_OFFSET, y + COORD_OFFSET, walter_mode(cw, delay)]
        args += [0] * (7 - len(args))
        frames.append(encode_command("WalterGoal", *args))
    return frames


def encode_walter_log(round_: int, flags: int, position: int, delay: int) -> bytes:
    """The control board's debug line of a Walter round: ``"WLK"`` round flags position delay."""
    return WALTER_LOG_TAG + bytes([round_ & 0xFF, flags & 0xFF, position & 0xFF, delay & 0xFF]) + EOL


def walter_log_view(body: bytes) -> dict[str, Any]:
    """Decode the four bytes after ``WLK``; the goal is entry ``position`` of the goal table."""
    r, flags, position, delay = body[:4]
    view: dict[str, Any] = {"round": r, "delay": delay,
                            "position": None if position == WALTER_NO_POSITION else position}
    for f in WalterFlag:
        view[f.name.lower()] = bool(flags & f)
    view["direction"] = ("CW" if flags & WalterFlag.CW else "CCW") if position != WALTER_NO_POSITION \
        else None
    return view

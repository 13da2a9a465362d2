"""``hexbench boards``: which HexBot board answers on which serial port.

The ports given on the command line (devices, ptys and URLs), or with none given the serial
adapters pyserial finds (``serial.tools.list_ports``: device, USB serial number, description,
the ``/dev/serial/by-id`` name pointing at it), are each opened at the IR baud rate as the
PC's central transceiver (:class:`~hexbench.serial_pc.SerialPc`), all at once (a thread each,
a few seconds each), and asked what answers:

* ``Report`` (61): a v2 module answers its ``POS`` line (id, cell, Yref, localized, role), then
  ACK 61; a thesis-2009 module does not know the code: ACK ``'N'``;
* ``Version`` (63), to a module that answered Report: ``VER`` major minor profile, then ACK 63
  (``'N'`` from v2 firmware older than the code);
* several modules in front of one transceiver answer at once: more than one ``POS``, or noise
  (their bytes collide).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from bus import UsageError
from bus.codec import Frame, Kind, encode_command, noise
from bus.functions import ACK_UNKNOWN, FunctionCode
from bus.timing import Baud

from .args import baud

#: Where udev keeps stable names for USB serial adapters (one symlink per adapter).
BY_ID = Path("/dev/serial/by-id")
#: At most this long for a line that is busy when the port opens to go quiet (a booting module).
SETTLE_S = 1.5
THESIS = "thesis-2009 (or a module without v2)"
OK, ERROR = 0, 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "boards", help="which HexBot board answers on which serial port",
        description="Ask the PORTs given, or with none the serial adapters pyserial finds "
                    "(list_ports: USB serial number, /dev/serial/by-id name): open each at the IR baud rate as "
                    "the PC's central transceiver and ask what answers (v2 Report and Version; a "
                    "thesis-2009 module answers 'N'), all ports at once. Exit 0 if a board "
                    "answered, 1 if none did, 2 on usage errors. See docs/hil.md.")
    p.add_argument("ports", nargs="*", metavar="PORT",
                   help="the ports or pyserial URLs to ask, and only these (ptys and socket:// URLs "
                        "are not listed by list_ports), e.g. /dev/ttyUSB0 /tmp/hx1 socket://lab-pi:7000; "
                        "none: every adapter list_ports finds")
    p.add_argument("--scan", action="store_true",
                   help="with PORTs: ask the adapters list_ports finds as well")
    p.add_argument("--baud", type=baud, default=int(Baud.IR), help="IR baud rate (default 300)")
    p.add_argument("--timeout", type=float, default=3.0,
                   help="seconds to wait for each answer (default 3; a substrate answers 1 s late)")
    p.add_argument("--json", action="store_true", help="one JSON object per port instead of the table")
    p.set_defaults(func=cmd_boards)


# -- which ports ---------------------------------------------------------------------------------
@dataclass
class Port:
    """A port to ask: ``url`` is what is opened; the rest is what list_ports knows of it."""

    url: str
    device: str = ""
    serial_number: str | None = None
    description: str = ""
    by_id: str | None = None

    @property
    def name(self) -> str:
        """The name to use elsewhere (``--real ID=<name>``): the by-id link survives a replug."""
        return self.by_id or self.url


def _by_id() -> dict[str, str]:
    """Each device's ``/dev/serial/by-id`` link, by the device it resolves to."""
    try:
        links = sorted(BY_ID.iterdir())
    except OSError:
        return {}
    return {os.path.realpath(link): str(link) for link in links}


def adapters() -> list[Port]:
    """The serial adapters pyserial finds, by device name."""
    from serial.tools import list_ports

    links = _by_id()
    return [Port(info.device, info.device, info.serial_number,
                 "" if info.description in (None, "n/a") else info.description,
                 links.get(os.path.realpath(info.device)))
            for info in sorted(list_ports.comports(), key=lambda i: i.device)]


def ports_to_ask(given: list[str], *, scan: bool = False) -> list[Port]:
    """The ports given, and only these (a board owner may have other devices on other ports);
    with none given, or with ``scan``, the adapters found come first. A given path that names a
    found adapter (e.g. its by-id link) is that adapter, opened by the name given; listing the
    adapters opens none of them."""
    import serial

    found = adapters()
    links = _by_id()
    by_device = {os.path.realpath(p.device): p for p in found}
    ports = list(found) if scan or not given else []
    for url in given:
        if "://" in url:
            try:
                serial.serial_for_url(url, do_not_open=True)
            except ValueError as exc:  # an unknown scheme
                raise UsageError(f"{url}: {exc}") from None
        elif (adapter := by_device.get(os.path.realpath(url))) is not None:
            adapter.url = url
            if all(p is not adapter for p in ports):
                ports.append(adapter)
            continue
        if all(p.url != url for p in ports):
            ports.append(Port(url, url, by_id=None if "://" in url else links.get(os.path.realpath(url))))
    return ports


# -- what answers --------------------------------------------------------------------------------
@dataclass
class Answer:
    """What one port said: the frames heard before asking (``before``), after ``Report`` and after
    ``Version``, each list without the echo of the PC's own frame (some IR adapters echo it)."""

    port: Port
    error: str | None = None  # the port could not be opened
    bad_url: bool = False
    before: list[Frame] = field(default_factory=list)
    report: list[Frame] = field(default_factory=list)
    version: list[Frame] = field(default_factory=list)
    echo: bool = False
    seconds: float = 0.0

    def _all(self) -> list[Frame]:
        return self.before + self.report + self.version

    def _ack(self, frames: list[Frame]) -> int | None:
        return next((f.view["byte"] for f in frames if f.kind is Kind.ACK), None)

    @property
    def positions(self) -> list[dict]:
        return [f.view for f in self._all() if f.kind is Kind.POSITION]

    @property
    def ids(self) -> list[int]:
        return sorted({v["id"] for v in self.positions})

    @property
    def noise_bytes(self) -> int:
        return sum(len(f.raw) for f in self._all() if f.kind is Kind.NOISE)

    @property
    def banners(self) -> list[str]:
        return [f.view["banner"] for f in self._all() if f.kind is Kind.BANNER]

    @property
    def firmware(self) -> dict | None:
        return next((f.view for f in self.version if f.kind is Kind.VERSION), None)

    @property
    def role(self) -> str | None:
        pos = self.positions
        if pos:
            return "substrate" if pos[0]["substrate"] else "mobile" if pos[0]["mobile"] else None
        role = next((f.view.get("role") for f in self._all() if f.kind is Kind.ACK), None)
        return {"M": "mobile", "S": "substrate"}.get(role or "", None)

    @property
    def collided(self) -> bool:
        """Several modules answered at once: more than one POS or ACK to one command, or noise."""
        acks = max(sum(f.kind is Kind.ACK for f in frames) for frames in (self.report, self.version))
        return len(self.positions) > 1 or acks > 1 or self.noise_bytes > 0

    @property
    def kind(self) -> str:
        """``v2``, ``thesis-2009``, ``garbled``, ``booting``, ``no answer`` or ``cannot open``."""
        if self.error is not None:
            return "cannot open"
        if self.positions or self._ack(self.report) == FunctionCode.Report:
            return "v2"
        if self._ack(self.report) == ACK_UNKNOWN:
            return "thesis-2009"
        if self.noise_bytes:
            return "garbled"
        if self.banners:
            return "booting"
        return "no answer"

    @property
    def answered(self) -> bool:
        return self.kind in ("v2", "thesis-2009")

    def what(self) -> str:
        """One line: who answered."""
        kind = self.kind
        if kind == "cannot open":
            return f"cannot open: {self.error}"
        if kind == "garbled":
            return (f"garbled: {self.noise_bytes} byte(s) that are no frame (several modules "
                    "answering at once, or a wrong baud rate)")
        if kind == "booting":
            return f"a module booting (heard {', '.join(self.banners)}) and no answer yet"
        if kind == "no answer":
            return "no answer"
        role = f", {self.role}" if self.role else ""
        if kind == "thesis-2009":
            text = f"{THESIS}: 'N' to Report{role}"
        elif len(self.ids) > 1:
            text = f"modules {', '.join(map(str, self.ids))}: v2{role}"
        else:
            text = f"module {self.ids[0] if self.ids else '?'}: v2, {self._firmware()}{self._where()}{role}"
        if self.collided:
            text += (f"; {len(self.positions)} POS lines" if len(self.positions) > 1 else "") + \
                    (f"; {self.noise_bytes} noise byte(s)" if self.noise_bytes else "") + \
                    ": several modules answer at once (collisions)"
        return text

    def _firmware(self) -> str:
        fw = self.firmware
        if fw is not None:
            return f"firmware {fw['version']}" + ("" if fw["profile"] == "v2" else f" profile {fw['profile']}")
        if self._ack(self.version) == ACK_UNKNOWN:
            return "firmware without Version (before 2.1)"
        return "firmware ? (no answer to Version)"

    def _where(self) -> str:
        pos = self.positions
        if not pos:
            return ", no POS line"
        v = pos[0]
        return f", localized at ({v['x']}, {v['y']}) Yref {v['yref']}" if v["localized"] else ", not localized"

    def next_step(self) -> str:
        kind, name = self.kind, self.port.name
        if self.collided and self.answered or kind == "garbled":
            return ("leave one module in front of this transceiver and run again"
                    + (" (or check --baud: HexBot IR is 300)" if kind == "garbled" else ""))
        if kind == "v2":
            return f"hexbench run <scenario> --real {self.ids[0] if self.ids else '<ID>'}={name}"
        if kind == "thesis-2009":
            return (f"hexbench run <scenario> --profile thesis-2009 --planner script:<file> "
                    f"--real <ID>={name}  (ID: its DIP switches)")
        if kind == "booting":
            return "wait until it has booted (COMM. LISTENING, about 8 s) and run again"
        if kind == "cannot open":
            return ("check the host, the port number and that ser2net runs there" if "://" in self.port.url
                    else "check the name and your permissions (the dialout group), and that no "
                         "other program holds the port")
        return ("power-cycle the module and try again; check that it faces the transceiver, "
                "the adapter, and the baud (--baud)")

    def to_json(self) -> dict:
        pos = self.positions[0] if self.positions else {}
        fw = self.firmware or {}
        p = self.port
        return {"port": p.url, "device": p.device, "by_id": p.by_id, "usb_serial": p.serial_number,
                "description": p.description, "kind": self.kind, "answered": self.answered,
                "ids": self.ids, "profile": {"v2": "v2", "thesis-2009": "thesis-2009"}.get(self.kind),
                "firmware": fw.get("version"), "localized": pos.get("localized"), "role": self.role,
                "collisions": self.collided, "noise_bytes": self.noise_bytes, "echo": self.echo,
                "what": self.what(), "next": self.next_step(), "seconds": round(self.seconds, 2),
                "frames": [f.describe() for f in self._all()]}


def _heard(answer: Answer, frames: list[Frame], sent: bytes) -> list[Frame]:
    """The frames without the echo of ``sent`` (a noise frame holding it)."""
    out = []
    for f in frames:
        if sent and f.kind is Kind.NOISE and sent in f.raw:
            answer.echo = True
            rest = f.raw.replace(sent, b"", 1)
            if not rest:
                continue
            f = noise(f.link, rest, f.view["reason"])
        out.append(f)
    return out


def ask_port(port: Port, *, baud: int = Baud.IR, timeout_s: float = 3.0) -> Answer:
    """Open ``port`` as the PC's central transceiver and ask what answers (a few seconds)."""
    import serial

    from .serial_pc import SerialPc, open_exclusive

    t0 = time.monotonic()
    answer = Answer(port)
    try:
        spc = SerialPc(port.url, baud=baud, name="boards", opener=open_exclusive)
    except (serial.SerialException, OSError, ValueError) as exc:
        errno = getattr(exc, "errno", None)  # pyserial repeats the path twice around it
        answer.error = os.strerror(errno) if isinstance(errno, int) else str(exc) or type(exc).__name__
        answer.bad_url = isinstance(exc, ValueError)
        answer.seconds = time.monotonic() - t0
        return answer
    received = spc.pc.received
    try:
        spc.quiet(timeout_s=SETTLE_S)
        answer.before = [r.frame for r in received]
        for code, into in ((FunctionCode.Report, answer.report), (FunctionCode.Version, answer.version)):
            mark, frame = len(received), encode_command(code)
            _, ack = spc.ask(frame, timeout_s=timeout_s)
            spc.quiet(timeout_s=SETTLE_S)  # late answers of other modules, an echo's tail
            into += _heard(answer, [r.frame for r in received[mark:]], frame)
            if ack is None or ack.frame.view["byte"] != code:
                break  # a thesis module ('N') or nobody: Version would say no more
    finally:
        spc.close()
    answer.seconds = time.monotonic() - t0
    return answer


# -- the command -----------------------------------------------------------------------------------
def table(answers: list[Answer]) -> str:
    """Plain aligned text: a row per port, the adapter's device and description under it."""
    rows = [("PORT", "USB SERIAL", "ANSWER", "NEXT STEP")]
    rows += [(a.port.name, a.port.serial_number or "-", a.what(), a.next_step()) for a in answers]
    widths = [max(len(r[k]) for r in rows) for k in range(3)]
    lines = []
    for i, r in enumerate(rows):
        lines.append("  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[3])
        if i:
            p = answers[i - 1].port
            about = [x for x in (p.device if p.device != p.name else "", p.description) if x]
            if about:
                lines.append("  " + ", ".join(about))
    return "\n".join(line.rstrip() for line in lines)


def cmd_boards(args: argparse.Namespace) -> int:
    if args.timeout <= 0:
        raise UsageError(f"--timeout {args.timeout:g}: expected seconds > 0")
    ports = ports_to_ask(args.ports, scan=args.scan)
    if not ports:
        print("hexbench boards: no serial adapter found (pyserial list_ports); give ports or URLs: "
              "hexbench boards /dev/ttyUSB0 socket://lab-pi:7000", file=sys.stderr)
        return ERROR
    print(f"asking {len(ports)} port(s) at {args.baud} baud: Report, then Version "
          f"(up to {args.timeout:g} s an answer)...", file=sys.stderr, flush=True)
    with ThreadPoolExecutor(max_workers=len(ports), thread_name_prefix="boards") as pool:
        answers = list(pool.map(lambda p: ask_port(p, baud=args.baud, timeout_s=args.timeout), ports))
    if args.json:
        print(json.dumps([a.to_json() for a in answers], indent=2))
    else:
        print(table(answers))
    bad = [a for a in answers if a.bad_url]
    if bad:
        raise UsageError("; ".join(f"{a.port.url}: {a.error}" for a in bad))
    return OK if any(a.answered for a in answers) else ERROR


__all__ = ["Answer", "Port", "adapters", "ask_port", "cmd_boards", "ports_to_ask", "register", "table"]

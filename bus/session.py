"""Opening a zenoh session the hexbench way (ARCHITECTURE principle 7).

Default: an embedded peer bound to loopback only. The first hexbench process on
a machine listens on the well-known endpoint ``tcp/127.0.0.1:7557``; later ones
find it taken, listen on a free loopback port and connect to it, so two
``hexbench`` processes started with no flags find each other. Multicast
scouting is off (no traffic leaves the machine unless asked).

``--connect``/``--listen`` take zenoh endpoints (``tcp/host:port``) to spread a
fleet over hosts, and ``--mode router`` runs a router for them. Security is zenoh's own:
``--zenoh-config FILE`` (a zenoh JSON5 configuration: TLS certificates, access control) is
the base every option above is applied to. Listening beyond loopback without TLS is warned
about: anyone who reaches the port can put on the fleet's keys.

A ``--connect`` endpoint the session cannot reach is named with its cause, in one line
(:func:`endpoint_problem`): nothing listens there, or something does but the TLS handshake
failed. zenoh says only "Unable to connect" in client mode, and nothing in peer mode (a peer
keeps trying), so the cause comes from a plain TCP probe of the endpoint.
"""

from __future__ import annotations

import json
import socket
import sys
import time
from dataclasses import dataclass, field

import zenoh

from .errors import HexbenchError, UsageError

WELL_KNOWN = "tcp/127.0.0.1:7557"


@dataclass
class SessionOptions:
    mode: str = "peer"  # "peer", "client" or "router"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    isolated: bool = False  # tests: a private loopback peer that joins nobody
    config: str | None = None  # a zenoh JSON5 configuration file to start from
    require_connect: bool = False  # a peer that reaches none of --connect fails (else: warned)

    @classmethod
    def from_args(cls, args: object) -> "SessionOptions":
        """From ``add_arguments``' options. A run on the virtual clock (``args.clock``) is one
        process: unless told where to connect or listen it is isolated, because samples
        from other processes would break its determinism."""
        connect = list(getattr(args, "connect", None) or [])
        listen = list(getattr(args, "listen", None) or [])
        virtual_alone = getattr(args, "clock", None) == "virtual" and not (connect or listen)
        return cls(mode=getattr(args, "mode", None) or "peer", connect=connect, listen=listen,
                   isolated=bool(getattr(args, "isolated", False)) or virtual_alone,
                   config=getattr(args, "zenoh_config", None),
                   require_connect=bool(getattr(args, "require_connect", False)))


def _config(mode: str, listen: list[str], connect: list[str], base: str | None = None) -> zenoh.Config:
    try:
        conf = zenoh.Config.from_file(base) if base else zenoh.Config()
    except zenoh.ZError as exc:
        raise UsageError(f"--zenoh-config {base}: {' '.join(str(exc).split(' at /')[0].split())}") from None
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    return conf


def open_session(opts: SessionOptions | None = None) -> zenoh.Session:
    """Open a session following the defaults above."""
    opts = opts or SessionOptions()
    base = opts.config
    if opts.isolated:
        return zenoh.open(_config("peer", ["tcp/127.0.0.1:0"], [], base))
    if opts.connect or opts.listen or opts.mode != "peer":
        listen = opts.listen or (["tcp/127.0.0.1:0"] if opts.mode != "client" else [])
        for ep in listen:
            if not _private(ep):
                print(f"warning: listening on {ep} without TLS: anyone who reaches it can put on "
                      "the fleet's keys (world/inject, ir/tx/pc); use tls/... with --zenoh-config "
                      "(docs/bus.md)", file=sys.stderr)
        return _open_connected(opts, _config(opts.mode, listen, opts.connect, base))
    try:
        return zenoh.open(_config("peer", [WELL_KNOWN], [], base))
    except zenoh.ZError:
        # Someone on this machine already holds the well-known endpoint: join it.
        return zenoh.open(_config("peer", ["tcp/127.0.0.1:0"], [WELL_KNOWN], base))


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on ``host`` nobody listens on now (the kernel's choice), for a zenoh listener
    (``tcp/127.0.0.1:<port>``). Nothing holds it: bind it soon."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


class ConnectError(HexbenchError):
    """A ``--connect`` endpoint that could not be reached; the message names it and why."""


def _open_connected(opts: SessionOptions, conf: zenoh.Config) -> zenoh.Session:
    """Open a session with ``--connect`` endpoints and say, in one line, which it could not
    reach and why: a client fails (:class:`ConnectError`); a peer or a router is warned about,
    since zenoh keeps trying (with ``require_connect``, one that reaches none of them fails)."""
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        if opts.connect and "connect" in str(exc).lower():
            raise ConnectError(_causes(opts.connect)) from None
        raise
    missing = _unreached(session, opts.connect) if opts.connect and opts.mode != "client" else []
    if missing and opts.require_connect and len(missing) == len(opts.connect):
        session.close()
        raise ConnectError(_causes(missing))
    if missing:
        print(f"warning: {_causes(missing)} (zenoh keeps trying)", file=sys.stderr)
    return session


def _unreached(session: zenoh.Session, endpoints: list[str], wait_s: float = 1.5) -> list[str]:
    """The ``endpoints`` ``session`` holds no link to after up to ``wait_s`` (a peer's open
    waits half a second for its connections, a TLS handshake may take longer)."""
    wanted = {ep: _addresses(ep) for ep in endpoints}
    deadline = time.monotonic() + wait_s
    while True:
        linked = {str(link.dst).split("#")[0].split("?")[0] for link in session.info.links()}
        missing = [ep for ep, addrs in wanted.items() if addrs is not None and not addrs & linked]
        if not missing or time.monotonic() >= deadline:
            return missing
        time.sleep(0.05)


def _causes(endpoints: list[str]) -> str:
    return "; ".join(endpoint_problem(ep) for ep in endpoints)


def _split(endpoint: str) -> tuple[str, str, int] | None:
    """``tls/host:7447?x#y`` as (``tls``, ``host``, 7447); None for other forms."""
    proto, _, rest = endpoint.split("#")[0].split("?")[0].partition("/")
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit():
        return None
    return proto, host.strip("[]"), int(port)


def _addresses(endpoint: str) -> set[str] | None:
    """The locators a link to ``endpoint`` shows as its ``dst`` (the host name resolved);
    None when they cannot be told (a name that does not resolve is then reported as unreached)."""
    parts = _split(endpoint)
    if parts is None:
        return None
    proto, host, port = parts
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError:
        return set()
    return {f"{proto}/{'[%s]' % a[4][0] if a[0] == socket.AF_INET6 else a[4][0]}:{port}" for a in infos}


def endpoint_problem(endpoint: str, timeout_s: float = 2.0) -> str:
    """Why a session could not reach ``endpoint``, in one line: a plain TCP connect tells
    "nothing listens" from "something listens, but no zenoh session came of it" (for ``tls/``:
    the TLS handshake was refused, most often a missing or wrong CA)."""
    parts = _split(endpoint)
    if parts is None or parts[0] not in ("tcp", "tls"):
        return f"cannot connect to {endpoint}"
    proto, host, port = parts
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            pass
    except socket.gaierror:
        return f"cannot connect to {endpoint}: unknown host {host}"
    except ConnectionRefusedError:
        return f"nothing listens at {endpoint}"
    except TimeoutError:
        return f"cannot connect to {endpoint}: no answer in {timeout_s:g} s (host down or a firewall)"
    except OSError as exc:
        return f"cannot connect to {endpoint}: {exc.strerror or exc}"
    if proto == "tls":
        return f"cannot connect to {endpoint}: TLS handshake refused (check the CA in --zenoh-config)"
    return (f"cannot connect to {endpoint}: something listens there but no zenoh session opened "
            "(a TLS listener? then tls/...; or its --zenoh-config refused this one)")


def _private(endpoint: str) -> bool:
    """An endpoint nobody else can reach unencrypted: TLS/QUIC, or loopback."""
    proto, _, rest = endpoint.partition("/")
    if proto in ("tls", "quic", "unixsock-stream"):
        return True
    host = rest.rsplit(":", 1)[0].strip("[]")
    return host in ("localhost", "::1") or host.startswith("127.")


def add_arguments(parser) -> None:  # argparse.ArgumentParser
    g = parser.add_argument_group("bus (zenoh)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="zenoh endpoint to connect to, e.g. tcp/10.0.0.5:7447 (repeatable)")
    g.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="zenoh endpoint to listen on (repeatable)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer",
                   help="zenoh mode (default: peer)")
    g.add_argument("--zenoh-config", metavar="FILE",
                   help="a zenoh JSON5 config to start from: TLS certificates, access control "
                        "(docs/bus.md); the options above are applied on top")
    g.add_argument("--isolated", action="store_true",
                   help="private loopback session that joins no other process")
    g.add_argument("--fleet", default="default", help="fleet name: keys live under hexbot/<fleet>/")

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
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field

import zenoh

from .errors import UsageError

WELL_KNOWN = "tcp/127.0.0.1:7557"


@dataclass
class SessionOptions:
    mode: str = "peer"  # "peer", "client" or "router"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    isolated: bool = False  # tests: a private loopback peer that joins nobody
    config: str | None = None  # a zenoh JSON5 configuration file to start from

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
                   config=getattr(args, "zenoh_config", None))


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
        return zenoh.open(_config(opts.mode, listen, opts.connect, base))
    try:
        return zenoh.open(_config("peer", [WELL_KNOWN], [], base))
    except zenoh.ZError:
        # Someone on this machine already holds the well-known endpoint: join it.
        return zenoh.open(_config("peer", ["tcp/127.0.0.1:0"], [WELL_KNOWN], base))


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

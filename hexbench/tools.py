"""Subcommands over the contract itself: ``decode``, ``encode``, ``send``, ``scenarios``,
``monitor``; and ``demo``."""

from __future__ import annotations

import argparse
import json
import re
import sys

from bus import (Envelope, Framer, Link, UsageError, add_bus_arguments, encode_command, lookup,
                 open_bus, parse)

from .live import add_live_argument, start_live


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("decode", help="decode hex bytes of a link into frames",
                       description="Print each frame found in hex bytes: kind, function and "
                                   "arguments, or noise with the reason.")
    p.add_argument("--link", required=True, help="one of: " + ", ".join(link.value for link in Link))
    p.add_argument("hex", nargs="+", help="bytes in hex; spaces, colons and 0x are ignored")
    p.set_defaults(func=cmd_decode)

    p = sub.add_parser("encode", help="build a PC command frame and print it in hex")
    p.add_argument("function", help="name or code, e.g. MCW or 21")
    p.add_argument("args", nargs="*", type=int, help="argument bytes in Table 3-8 order")
    p.set_defaults(func=cmd_encode)

    p = sub.add_parser("send", help="send one command to a running fleet or bridge, print the answer",
                       description="Like cansend: join a running fleet (or a hil bridge) over the "
                                   "bus as the PC, send one command frame on the centre channel, "
                                   "wait for the answer and print it decoded. Exit 0 for an ACK, "
                                   "1 for 'N' (unknown code), 3 for no answer (a --connect endpoint "
                                   "not reached, no fleet on the bus, or '~': the control board did "
                                   "not echo), 2 for a bad command.")
    p.add_argument("function", help="name or code, e.g. SxP or 11")
    p.add_argument("args", nargs="*", type=int, help="argument bytes in Table 3-8 order")
    p.add_argument("--select", type=int, metavar="ID",
                   help="first Select(1, ID, 0): only module ID obeys and answers")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the answer")
    p.add_argument("--baud", type=int, default=300, help="IR baud rate (default 300)")
    p.add_argument("--clock", choices=["wall"], default="wall", help=argparse.SUPPRESS)
    add_bus_arguments(p)
    p.set_defaults(func=cmd_send, require_connect=True)  # a --connect not reached: said at once

    p = sub.add_parser("scenarios", help="list the built-in scenarios, or show one")
    p.add_argument("name", nargs="?", help="a built-in name or a .toml path to check and show")
    p.set_defaults(func=cmd_scenarios)

    p = sub.add_parser("monitor", help="print frames and events on the bus as they pass")
    add_bus_arguments(p)
    p.add_argument("--link", action="append", help="only these links (repeatable)")
    p.add_argument("--table", action="store_true",
                   help="one row per link and sender (last frame, counts, rate, errors), "
                        "updated in place, like can.viewer")
    p.add_argument("--seconds", type=float, help="stop after this many seconds")
    add_live_argument(p)
    p.set_defaults(func=cmd_monitor)

    p = sub.add_parser("router", help="run a zenoh router that fleets spread over hosts connect to",
                       description="A zenoh router (mode router) and nothing else, until Ctrl-C: "
                                   "participants on other hosts give --connect to its endpoint. "
                                   "Security is zenoh's own (--zenoh-config: TLS, access control).")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on (repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="another router (repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", help="a zenoh JSON5 config to start from")
    p.add_argument("--seconds", type=float, help="stop after this many seconds")
    p.set_defaults(func=cmd_router)

    _add_demo(sub)


def _hex(words: list[str]) -> bytes:
    text = re.sub(r"0x|[\s:,]", "", " ".join(words), flags=re.I)
    if len(text) % 2 or not re.fullmatch(r"[0-9a-fA-F]*", text):
        raise UsageError(f"{' '.join(words)!r} is not hex bytes (expected pairs of 0-9a-f, "
                         "e.g. 2a15040804090000000023)")
    return bytes.fromhex(text)


def _link(name: str) -> Link:
    try:
        return Link(name)
    except ValueError:
        raise UsageError(f"no link {name!r}; links: {', '.join(link.value for link in Link)}") from None


def cmd_decode(args: argparse.Namespace) -> int:
    link = _link(args.link)
    data = _hex(args.hex)
    framer = Framer(link)
    for t in framer.feed(data) + framer.flush():
        print(t.frame.describe())
    return 0


def command_frame(function: str, values: list[int]) -> bytes:
    """A PC command frame from a function name or code and its argument bytes; a wrong count
    or value is a UsageError naming the function's signature (Table 3-7)."""
    try:
        fn = lookup(function)
    except (KeyError, ValueError) as exc:
        raise UsageError(str(exc).strip('"')) from None
    if len(values) != len(fn.args):  # no silent zeros for a forgotten argument
        sig = ", ".join(a.name for a in fn.args)
        missing = [a.name for a in fn.args[len(values):]]
        raise UsageError(f"{fn.name} ({fn.code}) takes {len(fn.args)} argument(s), {fn.name}({sig}); "
                         f"got {len(values)}" + (f": missing {', '.join(missing)}" if missing else ""))
    try:
        return encode_command(fn, *values)
    except (KeyError, ValueError) as exc:
        raise UsageError(str(exc).strip('"')) from None


def cmd_encode(args: argparse.Namespace) -> int:
    print(command_frame(args.function, args.args).hex())
    return 0


#: ``hexbench send`` exit statuses (cansend's spirit: a script can tell them apart)
SEND_ACK, SEND_UNKNOWN, SEND_TIMEOUT = 0, 1, 3


def cmd_send(args: argparse.Namespace) -> int:
    """Join a running fleet (or a hil bridge) as the PC, send one frame, print the answer."""
    from bus.functions import ACK_TIMEOUT, ACK_UNKNOWN
    from bus.session import ConnectError
    from planner_svc.endpoint import ExpectTimeout, PcEndpoint

    from .serial_pc import ask

    frame = command_frame(args.function, args.args)
    if args.clock != "wall":
        raise UsageError("send talks to a fleet in another process: only --clock wall")
    try:
        bus = open_bus(args)
    except ConnectError as exc:  # nothing listens there, or the TLS handshake failed
        print(f"hexbench send: {exc}", file=sys.stderr)
        return SEND_TIMEOUT
    try:
        pc = PcEndpoint(bus, baud=args.baud)
        if not bus.wait_remote(bus.keys.ir_tx(pc.name), timeout_s=args.timeout):
            print(f"hexbench send: no fleet or bridge listens on {bus.keys.root} "
                  f"(start one, or give --connect/--fleet)", file=sys.stderr)
            return SEND_TIMEOUT
        if args.select is not None:
            mark = len(pc.received)
            pc.send_raw(command_frame("Select", [1, args.select, 0]))
            try:
                pc.expect("ack", since=mark, timeout_s=args.timeout, byte=60)
            except ExpectTimeout:
                print(f"hexbench send: module {args.select} did not answer Select within "
                      f"{args.timeout:g} s", file=sys.stderr)
                return SEND_TIMEOUT
        collided: set[str] = set()
        bus.subscribe_json(bus.keys.event("world"),
                           lambda k, d: collided.update(d.get("sources", []))
                           if isinstance(d, dict) and d.get("kind") == "collision"
                           and d.get("receiver") == pc.name else None)
        print(f"sent {frame.hex()}  ({command_describe(frame)})", flush=True)
        answers, ack = ask(pc, frame, timeout_s=args.timeout)
        for r in answers:
            print(f"  {r.frame.describe()}")
        if ack is None:
            why = (f": the answers of {', '.join(sorted(collided))} collided at the PC's transceiver "
                   "(give --select ID)" if len(collided) > 1 else "")
            print(f"hexbench send: no ACK within {args.timeout:g} s{why}", file=sys.stderr)
            return SEND_TIMEOUT
        byte = ack.frame.view["byte"]
        return SEND_UNKNOWN if byte == ACK_UNKNOWN else SEND_TIMEOUT if byte == ACK_TIMEOUT else SEND_ACK
    finally:
        bus.close()


def command_describe(frame: bytes) -> str:
    return parse(Link.PC, frame).describe()


def cmd_router(args: argparse.Namespace) -> int:
    import signal
    import threading

    from bus.session import SessionOptions, open_session

    listen = args.listen or ["tcp/127.0.0.1:7447"]
    try:
        session = open_session(SessionOptions(mode="router", listen=listen, connect=args.connect or [],
                                              config=args.zenoh_config))
    except Exception as exc:  # zenoh.ZError: the endpoint is taken or malformed
        raise UsageError(f"router: cannot listen on {', '.join(listen)}: {str(exc).split(' at /')[0]}") from None
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print(f"router {session.zid()} listening on {', '.join(listen)}", flush=True)
    try:
        done.wait(args.seconds)
    except KeyboardInterrupt:
        pass
    session.close()
    return 0


def cmd_scenarios(args: argparse.Namespace) -> int:
    from bus.scenario import ScenarioError, builtin_names, load
    if not args.name:
        for n in builtin_names():
            print(f"{n:18} {load(n).description}")
        return 0
    try:
        s = load(args.name)
    except ScenarioError as exc:
        raise UsageError(str(exc)) from None
    print(json.dumps({
        "name": s.name, "profile": s.profile, "seed": s.seed, "fixed": list(s.fixed),
        "modules": [{"id": m.id, "cell": list(m.cell), "kind": m.kind, "orientation": m.orientation}
                    for m in s.modules],
        "goal": [list(c) for c in s.goal], "obstacles": [list(c) for c in s.obstacles],
    }, indent=2))
    return 0


#: Times above this are Unix times (a wall-clock fleet), not sim times (as recordings.player).
_EPOCH_NS = 10**17


class _Seconds:
    """Seconds to show for a sample's ``sim_time_ns``: sim time as it is on a virtual clock;
    on a wall clock (Unix times) from the first sample this monitor saw."""

    def __init__(self) -> None:
        self.t0: int | None = None

    def __call__(self, t_ns: int | None) -> str:
        if not isinstance(t_ns, int):
            return ""
        if self.t0 is None:
            self.t0 = t_ns if t_ns > _EPOCH_NS else 0
        return f"{(t_ns - self.t0) / 1e9:.3f}"


def cmd_monitor(args: argparse.Namespace) -> int:
    if args.table:
        return _monitor_table(args)
    bus = open_bus(args)
    clock = bus.clock
    links = set(args.link or [])

    seconds = _Seconds()

    def on_frame(env: Envelope) -> None:
        if not links or env.link in links:
            print(f"{seconds(env.sim_time_ns):>12} {env.link:10} {env.src:>10} -> {env.dst:<8} "
                  f"{env.frame.describe()}", flush=True)

    def on_event(key: str, payload: bytes) -> None:
        try:
            t = json.loads(payload).get("sim_time_ns")
        except (ValueError, AttributeError):
            t = None
        print(f"{seconds(t):>12} event {bus.keys.relative(key)} {payload.decode(errors='replace')}", flush=True)

    lives = start_live(args.live, bus)
    if lives:  # a late joiner: ask the world for its poses, so the live scene has every module
        bus.put_json(bus.keys.world_sync, {"from": "monitor"})
    bus.subscribe_frames(on_frame)
    bus.subscribe(f"{bus.keys.root}/event/**", on_event)
    bus.subscribe(bus.keys.world_event, on_event)
    try:
        clock.run(timeout_s=args.seconds)
    finally:
        for close in lives:
            close()
        bus.close()
    return 0


def _monitor_table(args: argparse.Namespace) -> int:
    """``monitor --table``, like can.viewer: one row per link and sender, updated in place."""
    from rich.console import Console
    from rich.live import Live
    from rich.table import Table

    bus = open_bus(args)
    clock = bus.clock
    links = set(args.link or [])
    rows: dict[tuple[str, str], dict] = {}
    seconds = _Seconds()

    def on_frame(env: Envelope) -> None:
        if links and env.link not in links:
            return
        seconds(env.sim_time_ns)  # the first sample sets the time base
        r = rows.setdefault((env.link, env.src), {"count": 0, "noise": 0, "first": env.sim_time_ns})
        r["count"] += 1
        r["noise"] += env.kind == "noise"
        r["last"] = env.sim_time_ns
        r["dst"] = env.dst
        r["what"] = env.frame.describe()

    def table() -> Table:
        t = Table(title=f"hexbench monitor: {bus.keys.root}", expand=True)
        for col in ("link", "source", "to", "frames", "errors", "rate /s", "last (s)", "last frame"):
            t.add_column(col, no_wrap=col != "last frame",
                         justify="right" if col in ("frames", "errors", "rate /s", "last (s)") else "left")
        for (link, src), r in sorted(rows.items()):
            span = (r["last"] - r["first"]) / 1e9
            rate = (r["count"] - 1) / span if span > 0 else 0.0
            t.add_row(link, src, r["dst"], str(r["count"]), str(r["noise"]), f"{rate:.1f}",
                      seconds(r['last']), r["what"])
        return t

    console = Console()
    bus.subscribe_frames(on_frame)
    try:
        with Live(table(), console=console, refresh_per_second=4, transient=False) as live:
            def refresh() -> None:
                live.update(table())
                clock.call_later(250_000_000, refresh)
            clock.call_later(250_000_000, refresh)
            clock.run(timeout_s=args.seconds)
            live.update(table())
    finally:
        bus.close()
    return 0


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="the end-to-end demo: thesis-6 run, MCAP, rerun replay",
                       description="Run thesis-6 on virtual modules with the thesis planner, "
                                   "record it to thesis-6.mcap and replay it to thesis-6.rrd "
                                   "(in --out, default the working directory).")
    p.add_argument("--out", help="directory for the files (default: the working directory)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo
    return run_demo(args)

"""Subcommands over recordings: ``record``, ``info``, ``replay``."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from bus.cli import UsageError


def register(sub: argparse._SubParsersAction) -> None:
    from bus.session import add_arguments

    p = sub.add_parser("record", help="record every sample of a fleet to MCAP",
                       description="Subscribe to hexbot/<fleet>/** and write every sample to an "
                                   "MCAP file (wall clock), until --seconds pass or Ctrl-C.")
    add_arguments(p)
    p.add_argument("--out", type=Path, help="output .mcap (default: hexbench-<date>-<time>.mcap)")
    p.add_argument("--rotate-mb", type=float, metavar="N", help="start a new file every N MB")
    p.add_argument("--rotate-s", type=float, metavar="N", help="start a new file every N seconds")
    p.add_argument("--seconds", type=float, metavar="N", help="stop after N seconds")
    p.add_argument("--flush-s", type=float, default=0.5, metavar="S",
                   help="flush to disk at least this often (default 0.5): what a crash may lose")
    p.add_argument("--compression", choices=["zstd", "lz4", "none"], default="zstd")
    p.add_argument("--meta", action="append", default=[], metavar="KEY=VALUE",
                   help="run metadata to store (scenario=..., profile=..., seed=...); repeatable")
    p.set_defaults(func=cmd_record)

    p = sub.add_parser("info", help="summarise a recording: duration, frames per link, errors",
                       description="Counts per link (and noise), errors, faults, channels and run "
                                   "metadata. Reads truncated files (a killed recorder) too.")
    p.add_argument("file", type=Path, help="a .mcap file (or the stem of rotated parts)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser("replay", help="replay a recording visually with rerun",
                       description="Build a rerun recording of the run: lattice, modules, moves, "
                                   "magnets, joints, LEDs, IR links, frames, planner overlays, plots.")
    p.add_argument("file", type=Path, help="a .mcap file (or the stem of rotated parts)")
    p.add_argument("--rrd", type=Path, help="write the replay to this .rrd file")
    p.add_argument("--spawn", action="store_true", help="open a rerun viewer")
    p.add_argument("--anim-ms", type=float, default=20.0, help="animation step of moves (default 20 ms)")
    p.set_defaults(func=cmd_replay)


def _parse_meta(items: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(f"--meta {item!r}: expected KEY=VALUE, e.g. scenario=thesis-6")
        try:
            out[key] = json.loads(value) if key not in ("scenario", "profile", "planner") else value
        except ValueError:
            out[key] = value
    return out


def cmd_record(args: argparse.Namespace) -> int:
    import signal

    from bus.clock import WallClock
    from bus.keys import check_chunk
    from bus.session import SessionOptions
    from bus.transport import Bus

    from .recorder import Recorder

    try:
        check_chunk(args.fleet, "fleet")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = args.out or Path(time.strftime("hexbench-%Y%m%d-%H%M%S.mcap"))
    clock = WallClock()
    bus = Bus(clock, args.fleet, options=SessionOptions.from_args(args))
    rec = Recorder(out, fleet=args.fleet, meta={"clock": "wall", **_parse_meta(args.meta)},
                   time_source="wall", compression=args.compression, flush_interval_s=args.flush_s,
                   rotate_bytes=None if args.rotate_mb is None else int(args.rotate_mb * 1e6),
                   rotate_s=args.rotate_s)
    signal.signal(signal.SIGTERM, lambda *_: clock.stop())
    try:
        rec.attach(bus)
        print(f"recording {bus.keys.all} to {rec.paths[0]}", flush=True)
        clock.run(timeout_s=args.seconds)
    except KeyboardInterrupt:
        pass
    finally:
        tally = rec.close()
        bus.close()
    links = ", ".join(f"{k} {n}" for k, n in sorted(tally.frames_by_link.items())) or "none"
    print(f"{tally.messages} samples, {tally.frames} frames ({links}), {tally.errors} errors "
          f"-> {', '.join(str(p) for p in rec.paths)}", file=sys.stderr)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from .reader import summary

    try:
        s = summary(args.file)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        print(json.dumps(s.to_dict(), indent=2, default=str))
        return 0
    t = s.tally
    print(f"file:       {', '.join(str(p) for p in s.paths)}")
    state = "complete" if s.complete else "no footer (recovered)"
    print(f"state:      {state}{'; ' + '; '.join(s.truncated) if s.truncated else ''}")
    print(f"duration:   {s.duration_s:.3f} s  ({t.messages} samples, compression {'/'.join(s.compression) or '-'})")
    print(f"frames:     {t.frames}  noise {t.noise}  errors {t.errors}  faults {t.faults}"
          + (f"  undecodable {s.undecodable}" if s.undecodable else ""))
    for link, n in sorted(t.frames_by_link.items()):
        noise = t.noise_by_link.get(link, 0)
        print(f"  {link:12} {n:8}" + (f"  ({noise} noise)" if noise else ""))
    if t.errors_by_kind:
        print("errors:     " + ", ".join(f"{k} {n}" for k, n in sorted(t.errors_by_kind.items())))
    if t.world_events_by_kind:
        print("world:      " + ", ".join(f"{k} {n}" for k, n in sorted(t.world_events_by_kind.items())))
    print("metadata:")
    for k, v in sorted(s.metadata.items()):
        print(f"  {k:14} {v if isinstance(v, str) else json.dumps(v)}")
    print(f"channels:   {len(s.channels)}")
    for topic, schema in sorted(s.channels.items()):
        print(f"  {topic:32} {schema:24} {t.by_topic.get(topic, 0)}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from .replay import replay

    if args.rrd is None and not args.spawn:
        raise UsageError("say where the replay goes: --rrd out.rrd and/or --spawn")
    try:
        st = replay(args.file, rrd=args.rrd, spawn=args.spawn, anim_step_ns=int(args.anim_ms * 1e6))
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    print(f"{st.samples} samples, {st.frames} frames, {st.sim_ns / 1e9:.3f} sim s in {st.wall_s:.2f} s "
          f"({st.speed:.0f}x real time)" + (f" -> {args.rrd}" if args.rrd else ""), file=sys.stderr)
    return 0

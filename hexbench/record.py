"""Subcommands over recordings: ``record``, ``info``, ``replay`` (rerun, or back onto the bus)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from bus import UsageError, WallClock, add_bus_arguments, open_bus


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("record", help="record every sample of a fleet to MCAP",
                       description="Subscribe to hexbot/<fleet>/** and write every sample to an "
                                   "MCAP file (wall clock), until --seconds pass or Ctrl-C.")
    add_bus_arguments(p)
    p.add_argument("--out", type=Path, help="output .mcap (default: hexbench-<date>-<time>.mcap)")
    p.add_argument("--rotate-mb", type=float, metavar="N", help="start a new file every N MB")
    p.add_argument("--rotate-s", type=float, metavar="N", help="start a new file every N seconds")
    p.add_argument("--seconds", type=float, metavar="N", help="stop after N seconds")
    p.add_argument("--sync", action="store_true",
                   help="joining a fleet that already runs: ask its world to republish every pose "
                        "and switch state, so the recording (its scene, the replay) starts with "
                        "every module where it is")
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

    p = sub.add_parser("recover", help="write a complete MCAP file from a damaged or cut-short one",
                       description="Copy every message that can still be read (damaged chunks "
                                   "skipped, a cut tail ended) with its channel, schema, times and "
                                   "metadata into a new file with footer, summary and index. Exit 0 "
                                   "if nothing was lost, 1 if something was (and say what), 2 for a "
                                   "file that is not MCAP.")
    p.add_argument("file", type=Path, help="the damaged .mcap (or the stem of rotated parts)")
    p.add_argument("out", type=Path, help="the complete .mcap to write")
    p.set_defaults(func=cmd_recover)

    p = sub.add_parser("replay", help="replay a recording with rerun, or back onto the bus",
                       description="--rrd/--spawn: build a rerun recording of the run (lattice, "
                                   "modules, moves, magnets, joints, LEDs, IR links, frames, planner "
                                   "overlays, plots). --to-bus: republish the frames of --links with "
                                   "their recorded timing (PC frames as IR light, origin 'replay'). "
                                   "--compare: rebuild the run (scenario, profile, seed from the "
                                   "recording) on a virtual clock, replay --links into it and report "
                                   "the first frame on the other links that differs; exit 1 if one does.")
    add_bus_arguments(p)
    p.add_argument("file", type=Path, help="a .mcap file (or the stem of rotated parts)")
    p.add_argument("--rrd", type=Path, help="write the replay to this .rrd file")
    p.add_argument("--spawn", action="store_true", help="open a rerun viewer")
    p.add_argument("--anim-ms", type=float, default=20.0, help="animation step of moves (default 20 ms)")
    g = p.add_argument_group("bus replay")
    g.add_argument("--to-bus", action="store_true",
                   help="republish the recorded frames of --links on the bus (wall clock)")
    g.add_argument("--links", default="pc", metavar="L[,L...]",
                   help="links to replay (default: pc, the PC's commands)")
    g.add_argument("--speed", type=float, default=1.0, metavar="N",
                   help="replay N times faster than recorded (default 1; bytes keep their wire time)")
    g.add_argument("--compare", action="store_true",
                   help="replay into a fresh virtual fleet of the recorded scenario and compare the "
                        "frames of the other links with the recording (implies --to-bus)")
    g.add_argument("--scenario", metavar="NAME|FILE",
                   help="with --compare: the scenario to rebuild (default: the recording's)")
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


#: When told to stop, the recorder keeps taking samples until none came for this long (what
#: peers had already sent is still on its way), but no longer than QUIET_MAX_S.
QUIET_S, QUIET_MAX_S = 0.5, 10.0


def _take_in_flight(clock, rec) -> None:
    """Record what was already sent to this process before stopping: nothing captured is lost."""
    last = [rec.messages, time.monotonic()]

    def quiet() -> bool:
        if rec.messages != last[0]:
            last[:] = [rec.messages, time.monotonic()]
        return time.monotonic() - last[1] >= QUIET_S

    print(f"stopping: taking what is still on its way (until {QUIET_S:g} s pass with none, at most "
          f"{QUIET_MAX_S:g} s; Ctrl-C again to stop now)", file=sys.stderr, flush=True)
    try:
        clock.run(until=quiet, timeout_s=QUIET_MAX_S)
    except KeyboardInterrupt:
        pass
    clock.drain(timeout_s=1.0)
    if time.monotonic() - last[1] < QUIET_S:  # samples were still coming: say so, do not hide it
        print(f"warning: samples were still arriving {QUIET_MAX_S:g} s after the stop; the recording "
              "ends there", file=sys.stderr)


def cmd_record(args: argparse.Namespace) -> int:
    import signal

    from recordings.recorder import Recorder

    out = args.out or Path(time.strftime("hexbench-%Y%m%d-%H%M%S.mcap"))
    bus = open_bus(args, WallClock())
    clock = bus.clock
    rec = Recorder(out, fleet=args.fleet, meta={"clock": "wall", **_parse_meta(args.meta)},
                   time_source="wall", compression=args.compression, flush_interval_s=args.flush_s,
                   rotate_bytes=None if args.rotate_mb is None else int(args.rotate_mb * 1e6),
                   rotate_s=args.rotate_s)
    signal.signal(signal.SIGTERM, lambda *_: clock.stop())
    try:
        rec.attach(bus)
        if args.sync:
            bus.put_json(bus.keys.world_sync, {"from": "recorder"})
        print(f"recording {bus.keys.all} to {rec.paths[0]}", flush=True)
        clock.run(timeout_s=args.seconds)
    except KeyboardInterrupt:
        pass
    finally:
        _take_in_flight(clock, rec)
        tally = rec.close()
        bus.close()
    links = ", ".join(f"{k} {n}" for k, n in sorted(tally.frames_by_link.items())) or "none"
    print(f"{tally.messages} samples, {tally.frames} frames ({links}), {tally.errors} errors "
          f"-> {', '.join(str(p) for p in rec.paths)}", file=sys.stderr)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from recordings.health import WHY, Health, health
    from recordings.reader import summary

    try:
        s = summary(args.file)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    if args.json:
        d = s.to_dict()
        d["health"] = health(args.file, s.channels).to_dict()
        print(json.dumps(d, indent=2, default=str))
        return 1 if s.damaged else 0
    t = s.tally
    _warn_damaged(s.damaged)
    print(f"file:       {', '.join(str(p) for p in s.paths)}")
    state = "complete" if s.complete else "no footer (recovered)"
    print(f"state:      {state}{'; ' + '; '.join(s.truncated) if s.truncated else ''}")
    print(f"duration:   {s.duration_s:.3f} s  ({t.messages} samples, compression {'/'.join(s.compression) or '-'})")
    h = health(args.file, s.channels) if t.errors_by_kind else Health()
    expected = sum(h.expected.values())
    print(f"frames:     {t.frames}  noise {t.noise}  errors {sum(h.errors.values())}"
          + (f" (and {expected} expected)" if expected else "") + f"  faults {t.faults}"
          + (f"  undecodable {s.undecodable}" if s.undecodable else ""))
    for link, n in sorted(t.frames_by_link.items()):
        noise = t.noise_by_link.get(link, 0)
        print(f"  {link:12} {n:8}" + (f"  ({noise} noise)" if noise else ""))
    if t.errors_by_kind:
        print("errors:     " + (", ".join(f"{k} {n}" for k, n in sorted(h.errors.items())) or "none"))
    for why, n in sorted(h.expected.items()):
        print(f"expected:   {why} {n} ({WHY[why]})")
    if t.world_events_by_kind:
        print("world:      " + ", ".join(f"{k} {n}" for k, n in sorted(t.world_events_by_kind.items())))
    print("metadata:")
    for k, v in sorted(s.metadata.items()):
        print(f"  {k:14} {v if isinstance(v, str) else json.dumps(v)}")
    print(f"channels:   {len(s.channels)}")
    for topic, schema in sorted(s.channels.items()):
        print(f"  {topic:32} {schema:24} {s.messages_on(topic)}")
    return 1 if s.damaged else 0


def _warn_damaged(damaged: list) -> None:
    """One stderr line per chunk a reader skipped (recordings.reader.Damage)."""
    for d in damaged:
        print(f"warning: {d.describe()}", file=sys.stderr)


def cmd_recover(args: argparse.Namespace) -> int:
    from recordings.recover import recover

    if args.out.resolve() == args.file.resolve():
        raise UsageError("write the recovered file somewhere else: the damaged one is the only copy")
    try:
        r = recover(args.file, args.out)
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    _warn_damaged(r.damaged)
    for t in r.truncated:
        print(f"warning: {t}: the scan ended there; what followed is lost", file=sys.stderr)
    print(f"recovered {r.messages} messages on {r.channels} channels, {r.metadata} metadata "
          f"record(s) -> {args.out}")
    return 1 if r.lost else 0


def cmd_replay(args: argparse.Namespace) -> int:
    if args.compare or args.to_bus:
        return cmd_bus_replay(args)
    from recordings.replay import replay

    if args.rrd is None and not args.spawn:
        raise UsageError("say where the replay goes: --rrd out.rrd and/or --spawn, or --to-bus")
    from .progress import Progress
    try:
        with Progress(stream=sys.stderr) as bar:
            st = replay(args.file, rrd=args.rrd, spawn=args.spawn, anim_step_ns=int(args.anim_ms * 1e6),
                        progress=lambda phase, done, total: bar.update(f"replay: {phase}", done, total))
    except FileNotFoundError as exc:
        raise UsageError(str(exc)) from None
    _warn_damaged(st.damaged)
    print(f"{st.samples} samples, {st.frames} frames, {st.sim_ns / 1e9:.3f} sim s in {st.wall_s:.2f} s "
          f"({st.speed:.0f}x real time)" + (f" -> {args.rrd}" if args.rrd else ""), file=sys.stderr)
    return 1 if st.damaged else 0


def cmd_bus_replay(args: argparse.Namespace) -> int:
    """``--to-bus`` (wall clock, onto whatever fleet listens) or ``--compare`` (virtual)."""
    from recordings.reader import parts_of

    from .bus_replay import parse_links

    try:
        links = parse_links(args.links)
        parts_of(args.file)
    except (ValueError, FileNotFoundError) as exc:
        raise UsageError(str(exc)) from None
    if args.speed <= 0:
        raise UsageError(f"--speed must be positive, got {args.speed}")
    if args.compare:
        from .compare import CompareError, compare

        if args.speed != 1.0:
            raise UsageError("--compare replays at the recorded sim times on a virtual clock: "
                             "--speed does not apply")
        try:
            result = compare(args.file, links=links, scenario=args.scenario)
        except CompareError as exc:
            raise UsageError(str(exc)) from None
        print(result.report())
        return 0 if result.ok else 1
    if args.scenario:
        raise UsageError("--scenario only goes with --compare")

    from .bus_replay import BusReplay
    from .progress import Progress

    bus = open_bus(args, WallClock())
    clock = bus.clock
    try:
        replay = BusReplay.from_recording(bus, args.file, links=links, speed=args.speed)
        t0 = time.monotonic()
        replay.schedule(start_ns=clock.now_ns() + 500_000_000)  # a lead-in for peers to connect
        with Progress(stream=sys.stderr) as progress:
            def until() -> bool:
                progress.update("frames replayed", replay.sent, len(replay))
                return replay.done
            clock.run(until=until)
    except KeyboardInterrupt:
        return 130
    finally:
        bus.close()
    print(f"replayed {replay.sent} frame(s) on {', '.join(links)} to {bus.keys.root} "
          f"in {time.monotonic() - t0:.2f} s (speed {args.speed:g})", file=sys.stderr)
    return 0

"""``hexbench run`` and ``hexbench planner``: a planner run, with or without its fleet.

``hexbench run <scenario>`` puts the world, the virtual modules, the planner service and
(with ``--record``) the MCAP recorder on one bus and runs to the goal. ``hexbench planner
<scenario>`` is the planner service alone: it joins a fleet started elsewhere
(``hexbench fleet <scenario> --clock wall``) over zenoh.

:func:`cmd_run` reads as its steps: the options checked (:func:`_options`), the bus opened,
the set-up (:func:`_set_up`), the planner service's run, the end (:func:`_end`: shards, the
last samples, the summary). One ``ExitStack`` closes whatever was opened, in reverse order.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from bus import HexbenchError, UsageError, add_bus_arguments, open_bus
from bus.session import free_port

from .args import instant
from .fleet import LagNotice
from .live import add_live_argument, start_live
from .progress import Progress, phase_sayer

if TYPE_CHECKING:
    from bus import Bus, Scenario
    from bus.lockstep import Lockstep
    from module_sim.fleet import Fleet
    from planner_svc.planners.plan import Plan
    from planner_svc.service import PlannerService


def add_run_arguments(p: argparse.ArgumentParser, *, with_fleet: bool) -> None:
    p.add_argument("scenario", help="a built-in scenario name or a .toml file")
    p.add_argument("--planner",
                   help="planner name ('hexbench plan --list'), or script:<file>; default: the "
                        "scenario's planner, else thesis-serial")
    p.add_argument("--clock", choices=["virtual", "wall"], default="virtual" if with_fleet else "wall",
                   help="virtual: deterministic and as fast as the CPU allows (one process); "
                        "wall: real time, for hardware and other processes")
    p.add_argument("--seed", type=int, help="override the scenario's seed")
    p.add_argument("--profile", choices=["v2", "thesis-2009"], help="override the scenario's profile")
    p.add_argument("--timing", default="8,4,9", metavar="T1,T2,T3",
                   help="rotation delays in ticks (default: the thesis's 8,4,9)")
    p.add_argument("--real", action="append", default=[], metavar="ID=PORT[,DEBUG_PORT]",
                   help="module ID is a real board: its central IR transceiver on PORT and its "
                        "debug UART1 on DEBUG_PORT (pyserial URLs); repeatable. The world runs "
                        "a twin of it (docs/hil.md)")
    p.add_argument("--program", choices=["model", "firmware", "simavr"],
                   help="what virtual modules run: the Python programs (model, the reference), the "
                        "C firmware compiled for the host (firmware) or the flashed images in "
                        "simavr cores in-process (simavr) (docs/firmware.md); default: the "
                        "scenario's, else the firmware on the fleet core where the run allows it "
                        "(the virtual clock of one process, no bit errors), else model, saying why")
    p.add_argument("--firmware", action="append", default=[], metavar="ID",
                   help="module ID runs the C firmware (firmware/) in simavr, bridged like a real "
                        "board; repeatable; needs --clock wall (docs/firmware.md)")
    if with_fleet:
        p.add_argument("--record", type=Path, metavar="FILE.mcap", help="record the run to MCAP")
        p.add_argument("--start-time", type=instant, metavar="ISO8601",
                       help="virtual clock: the instant sim time 0 is in the recording's log times "
                            "(default: now; in the metadata as start_time)")
        p.add_argument("--compare-model", action="store_true",
                       help="with --program firmware --clock virtual: run the Python programs too "
                            "and report the first frame where the two runs differ (exit 1 if any)")
        p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                       help="inject an actuator fault through the world, e.g. m3.S2-:off or "
                            "m3.J4:closed (repeatable)")
        p.add_argument("--shards", type=int, metavar="N",
                       help="with --clock virtual: spread the fleet over N processes (hexbench fleet "
                            "--shard K/N, started here) on one lockstep clock: the same frames as one "
                            "process (docs/bus.md)")
        p.add_argument("--hil-port", metavar="URL",
                       help="the central IR transceiver of the scenario's real modules (any "
                            "pyserial URL); default: their 'port' in the scenario")
    add_live_argument(p)
    add_bus_arguments(p)


def _scenario(args: argparse.Namespace):
    from bus.scenario import ScenarioError, load, override

    try:
        return override(load(args.scenario), seed=args.seed, profile=args.profile,
                        faults=getattr(args, "fault", []), real=args.real,
                        firmware=getattr(args, "firmware", []),
                        program=getattr(args, "program", None))
    except ScenarioError as exc:
        raise UsageError(str(exc)) from None


def _start_firmware(scenario, stack: contextlib.ExitStack):
    """Start the simavr harness of every firmware module (closed with ``stack``); from then on
    each is a real board on the harness's two ptys."""
    import dataclasses

    from hil.firmware import FirmwareModule

    modules = []
    for m in scenario.modules:
        if m.kind == "firmware":
            fw = FirmwareModule(m.id, scenario.profile).start()
            stack.callback(fw.close)
            print(f"firmware: m{m.id} ({scenario.profile}) in simavr, IR on {fw.ir_path}, "
                  f"debug on {fw.debug_path}", flush=True)
            m = dataclasses.replace(m, kind="real", port=fw.ir_path, debug_port=fw.debug_path)
        modules.append(m)
    return dataclasses.replace(scenario, modules=modules)


def _bridges(bus, scenario, hil_port: str | None) -> list:
    """Serial bridges for the scenario's real modules: one for their shared central IR
    transceiver (``--hil-port`` or the modules' ``port``), one per ``debug_port``."""
    from hil.bridge import CentreBridge, DebugBridge

    real = [m for m in scenario.modules if m.kind == "real"]
    if not real:
        return []
    ports = sorted({hil_port} if hil_port else {m.port for m in real if m.port})
    if not ports:
        raise UsageError(f"scenario {scenario.name!r}: real modules need a serial port: give "
                         "--hil-port URL or 'port' in their [[modules]] entry")
    # wait=True: a port that is not there yet is a fault event and is retried, not a crash
    out = [CentreBridge(bus, url).start(wait=True) for url in ports]
    out += [DebugBridge(bus, m.debug_port, m.id).start(wait=True) for m in real if m.debug_port]
    for b in out:
        print(f"hil: bridging {b.url} ({b.link.value}) onto {bus.keys.root}", flush=True)
    return out


def _twin_checks(bus, scenario, fleet, bridges: list, hil_port: str | None) -> list:
    """A live differential for every real module alone on its port: its answers on the
    centre channel against its twin's (several boards behind one transceiver cannot be told
    apart there)."""
    from hil.bridge import FAULT, RECOVERED, DebugBridge
    from module_sim.twin import TwinCheck

    def say(d) -> None:
        print(f"{'twin view' if d.explained else 'twin diverged'}: {d.describe(bus.clock.started_ns)}",
              flush=True)

    def follow(check: TwinCheck, bridge) -> TwinCheck:
        """The check hears when the board's port goes and comes back (nobody hears the board
        meanwhile)."""
        def on_event(key: str, d: dict) -> None:
            if d.get("kind") == FAULT:
                check.line_down()
            elif d.get("kind") == RECOVERED:
                check.line_up(d["sim_time_ns"])
        bus.subscribe_json(bus.keys.event(bridge.name), on_event)
        return check

    real = [m for m in scenario.modules if m.kind == "real"]
    checks = []
    for bridge in bridges:
        if isinstance(bridge, DebugBridge):  # one board's debug lines and actuator reports
            checks.append(follow(TwinCheck(bus, fleet.twins[bridge.module_id], bridge.src,
                                           link="debug", on_difference=say), bridge))
            continue
        on_port = [m for m in real if (hil_port or m.port) == bridge.url]
        if len(on_port) != 1:
            if on_port:
                print(f"twin check: {len(on_port)} real modules share {bridge.url}: their answers "
                      "cannot be told apart there, so they are not compared with their twins",
                      flush=True)
            continue
        checks.append(follow(TwinCheck(bus, fleet.twins[on_port[0].id], bridge.src,
                                       on_difference=say), bridge))
    return checks


def _timing(text: str) -> tuple[int, int, int]:
    try:
        t = tuple(int(v) for v in text.split(","))
        if len(t) != 3 or not all(0 <= v <= 255 for v in t):
            raise ValueError
    except ValueError:
        raise UsageError(f"--timing {text!r}: expected three tick counts 0..255, e.g. 8,4,9") from None
    return t  # type: ignore[return-value]


#: Wall seconds the end of a run waits for its last bus samples to reach the recorder.
DRAIN_S = 5.0


@dataclass(frozen=True)
class RunOptions:
    """What a run was asked, checked (:func:`_options`); the command's ``args`` stay as given."""

    scenario: Scenario
    planner: str
    timing: tuple[int, int, int]
    with_fleet: bool  # False: ``hexbench planner``, joining a fleet elsewhere
    record: Path | None  # --compare-model without --record: a file of its own
    compare: bool
    shards: int | None
    bus_args: argparse.Namespace  # the options the bus and the shards open with
    plan: Plan | None = None  # made from the scenario before the fleet boots (_early_plan)


@dataclass
class RunParts:
    """What :func:`_set_up` started: for the run and its end."""

    bus: Bus
    service: PlannerService
    since_ns: int  # the clock when the run began
    lag: LagNotice | None = None  # a wall clock: the fleet's lag, here or elsewhere
    fleet: Fleet | None = None  # the fleet in this process
    checks: list = field(default_factory=list)  # live differentials of real modules with their twins
    step: Lockstep | None = None  # --shards: this process's side of the lockstep clock
    shards: list = field(default_factory=list)  # --shards: their processes


def cmd_run(args: argparse.Namespace, *, with_fleet: bool = True) -> int:
    opts = _options(args, with_fleet)  # a UsageError before anything is opened
    with contextlib.ExitStack() as stack:  # everything the run opens, closed in reverse order
        stack.enter_context(rarer_young_collections())
        bus = _open_bus(opts, stack)
        from planner_svc.planners import progress_unit
        # a bar on a terminal (moves n/N in steps, or in rounds), cleared before the summary lines
        with Progress(unit=progress_unit(opts.planner)) as progress:
            parts = _set_up(opts, args, bus, stack, progress)
            result = parts.service.run(parts.since_ns)
        _end(parts, result)
    if opts.compare:
        return _compare_model(args, opts.record, result.ok)
    return 0 if result.ok else 1


@contextlib.contextmanager
def rarer_young_collections(every: int = 50_000):
    """A run makes short-lived objects by the million (samples, envelopes, events); at Python's
    default (a young collection every 700 allocations) the collector took ~12 % of the
    127-module hexagon's wall time. Collecting every ``every`` costs a few MB and gives it
    back; the thresholds are restored after (``main`` also runs in-process, in tests)."""
    before = gc.get_threshold()
    gc.set_threshold(max(before[0], every), *before[1:])
    try:
        yield
    finally:
        gc.set_threshold(*before)


def _options(args: argparse.Namespace, with_fleet: bool) -> RunOptions:
    """Check the command's options against each other and the scenario."""
    from planner_svc import planners

    scenario = _scenario(args)
    # a scenario made for a planner (planner = "walter") runs with it unless told otherwise
    args.planner = args.planner or scenario.planner or planners.DEFAULT
    if args.planner == planners.WALTER:
        pass  # checked with the scenario by _early_plan
    elif not args.planner.startswith(planners.SCRIPT_PREFIX):
        try:
            planners.get(args.planner)
        except planners.UnknownPlanner as exc:
            raise UsageError(str(exc)) from None
    elif not Path(args.planner[len(planners.SCRIPT_PREFIX):]).is_file():
        raise UsageError(f"--planner {args.planner}: no such script file")
    timing = _timing(args.timing)
    if not with_fleet and args.clock == "virtual":
        raise UsageError("a planner in its own process needs --clock wall: a virtual clock cannot "
                         "be shared with a fleet in another process")
    real = [m for m in scenario.modules if m.kind in ("real", "firmware")]
    if real and args.clock == "virtual":
        raise UsageError(f"scenario {scenario.name!r} has real or firmware modules "
                         f"({', '.join(f'm{m.id}' for m in real)}): real hardware runs on the wall "
                         "clock; use --clock wall")
    compare = getattr(args, "compare_model", False)
    if compare and (scenario.program not in ("firmware", None) or args.clock != "virtual"):
        raise UsageError("--compare-model compares a firmware run with a model run on the virtual "
                         "clock: give --program firmware --clock virtual")
    if compare:
        import dataclasses
        scenario = dataclasses.replace(scenario, program="firmware")
    shards = getattr(args, "shards", None)
    bus_args = args
    if shards is not None:
        from .fleet import check_shardable
        if args.clock != "virtual":
            raise UsageError("--shards spreads a virtual run over processes: give --clock virtual")
        check_shardable(scenario, shards)
        if not (args.connect or args.listen):  # the shards join this process on loopback
            bus_args = argparse.Namespace(**{**vars(args), "listen": [f"tcp/127.0.0.1:{free_port()}"]})
    record = getattr(args, "record", None) if with_fleet else None
    if compare and record is None:
        import tempfile
        record = Path(tempfile.mkdtemp(prefix="hexbench-compare")) / "firmware.mcap"
    return RunOptions(scenario, args.planner, timing, with_fleet, record, compare, shards, bus_args,
                      _early_plan(scenario, args.planner))


def _early_plan(scenario: Scenario, planner: str) -> Plan | None:
    """The plan of the scenario, made before anything is opened, so that a plan that leaves
    what the protocol can name (bus.scenario.Reach) is refused in one line before the fleet
    boots; the service executes it when the fleet localizes as the scenario says. None for a
    script, and for thesis-2009 modules (no planner drives them)."""
    from planner_svc import planners
    from planner_svc.planners.plan import PlanError, check_reach

    if planner == planners.WALTER:
        from planner_svc.planners.walter import Inadmissible, choose
        from planner_svc.rounds import beyond_the_modules
        too_many = beyond_the_modules(len(scenario.modules))
        if too_many:  # whichever program the modules run: the C table's size is the limit
            raise UsageError(f"planner walter: {too_many}")
        try:  # an inadmissible goal is refused before anything moves
            choose(scenario.goal, scenario.initial, model=False)
        except Inadmissible as exc:
            raise UsageError(f"planner walter: {exc}") from None
        return None
    if planner.startswith(planners.SCRIPT_PREFIX) or scenario.profile == "thesis-2009":
        return None
    try:
        plan = planners.get(planner).plan(scenario)
    except PlanError:
        return None  # the service reports it with the rest of the run
    try:
        check_reach(plan, scenario.reach)
    except PlanError as exc:
        raise UsageError(f"planner {planner}: {exc}") from None
    return plan


def _open_bus(opts: RunOptions, stack: contextlib.ExitStack) -> Bus:
    """The run's bus (closed last); a sharded run's on a lockstep clock."""
    clock = None
    if opts.shards is not None:
        from bus.lockstep import LockstepClock
        clock = LockstepClock()
    bus = open_bus(opts.bus_args, clock)
    stack.callback(bus.close)
    return bus


def _set_up(opts: RunOptions, args: argparse.Namespace, bus: Bus, stack: contextlib.ExitStack,
            progress: Progress) -> RunParts:
    """Firmware harnesses, the recorder, live views, the planner service, then the fleet: here,
    in shard processes, or elsewhere (``hexbench planner``). What is opened closes with ``stack``."""
    from bus.messages import RunMeta
    from planner_svc.service import PlannerService

    bus.subscribe(bus.keys.planner("progress"), progress.on_planner_progress)
    scenario = _start_firmware(opts.scenario, stack) if opts.with_fleet else opts.scenario
    meta = RunMeta(scenario.name, scenario.profile, scenario.seed, opts.planner, args.clock,
                   list(sys.argv), {}, fleet=args.fleet)
    if opts.record is not None:
        from recordings.recorder import Recorder
        recorder = Recorder(opts.record, fleet=args.fleet, meta=meta, start_ns=getattr(args, "start_time", None))
        stack.callback(_close_recorder, recorder)
        recorder.attach(bus)
    for close in start_live(args.live, bus, meta=meta.to_dict()):
        stack.callback(close)
    bus.put(bus.keys.meta, meta.to_json())
    lag = LagNotice(bus, progress.say) if args.clock == "wall" else None
    since = bus.clock.now_ns()
    progress.say(f"run: scenario {scenario.name} ({len(scenario.modules)} modules, profile "
                 f"{scenario.profile}, seed {scenario.seed}), planner {opts.planner}, clock {args.clock}"
                 + (f", faults {', '.join(map(str, scenario.faults))}" if scenario.faults else ""))
    progress.phase("boot")
    service = PlannerService(bus, scenario, opts.planner, timing=opts.timing, say=phase_sayer(progress),
                             plan=opts.plan)
    parts = RunParts(bus, service, since, lag)
    if opts.shards is not None:
        from module_sim.fleet import Fleet
        note = Fleet.default_program(bus, scenario, refusal="a sharded fleet runs on a lockstep clock")[1]
        if note:
            progress.say(note)
        parts.step, parts.shards = _start_shards(opts.bus_args, bus, scenario, opts.shards, stack, progress)
    elif opts.with_fleet:  # after the service subscribed: it sees the world's first poses
        from module_sim.fleet import Fleet
        hil_port = getattr(args, "hil_port", None)
        bridges = _bridges(bus, scenario, hil_port)
        for b in bridges:
            stack.callback(b.close)
        parts.fleet = Fleet(bus, scenario)
        if parts.fleet.program_note:
            progress.say(parts.fleet.program_note)
        parts.checks = _twin_checks(bus, scenario, parts.fleet, bridges, hil_port)
        parts.fleet.power_up()
    return parts


def _close_recorder(recorder) -> None:
    tally = recorder.close()
    print(f"recorded {tally.frames} frames, {tally.messages} samples -> "
          f"{', '.join(map(str, recorder.paths))}", flush=True)


def _end(parts: RunParts, result) -> None:
    """After the planner's last word: the shards end with it, or the fleet's last samples reach
    the recorder; then the summary lines. A shard that failed makes the run fail, named."""
    failed: list[str] = []
    if parts.step is not None:
        parts.step.finish()  # every shard stops at this window's end
        failed = _end_shards(parts.shards)
        print(f"lockstep: {parts.step.window} windows of {parts.step.window_ns / 1e6:g} ms; "
              f"{parts.service.pc.conflicts} IR conflicts at the PC (corrections after their "
              "byte's stop bit)", flush=True)
    elif parts.fleet is not None:
        parts.fleet.world.mechanics.publish_run_energy()
        if not parts.bus.clock.drain(timeout_s=DRAIN_S):
            print(f"warning: some bus samples had not arrived after {DRAIN_S:g} s; the "
                  "recording may lack the last of them", flush=True)
    for check in parts.checks:
        print(check.summary(), flush=True)
    lag = "" if result.ok or parts.lag is None else parts.lag.cause()
    print(result.summary() + lag, flush=True)
    if failed:
        raise HexbenchError("; ".join(failed))


def _start_shards(args: argparse.Namespace, bus: Bus, scenario, n: int, stack: contextlib.ExitStack,
                  progress: Progress) -> tuple[Lockstep, list[subprocess.Popen]]:
    """The PC's part of the world here, the fleet in ``n`` shard processes, all on one lockstep
    clock (docs/bus.md). A run that fails leaves no shard running."""
    import tempfile

    from bus.lockstep import Lockstep
    from module_sim.shards import LAGS, PLANNER, participants, window_ns
    from module_sim.world import World

    children: list[subprocess.Popen] = []
    stack.callback(_stop_shards, children)
    w = window_ns(scenario.ir_baud)
    World(bus, scenario, own=set(), pc=True, physics=False, slack_ns=2 * w)  # light to the PC
    step = Lockstep(bus, PLANNER, participants(n), w, lags=LAGS)
    stack.callback(step.close)
    endpoints = args.connect or [ep.replace("0.0.0.0", "127.0.0.1") for ep in args.listen]
    for k in range(n):
        argv = [sys.executable, "-m", "hexbench", "fleet", args.scenario, "--clock", "virtual",
                "--shard", f"{k}/{n}", "--fleet", args.fleet, "--mode", args.mode]
        for ep in endpoints:
            argv += ["--connect", ep]
        for flag, value in (("--seed", args.seed), ("--profile", args.profile),
                            ("--program", args.program), ("--zenoh-config", args.zenoh_config)):
            if value is not None:
                argv += [flag, str(value)]
        for f in getattr(args, "fault", []):
            argv += ["--fault", f]
        log = stack.enter_context(tempfile.TemporaryFile(mode="w+"))
        child = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
        child.log = log  # type: ignore[attr-defined]
        children.append(child)
    progress.say(f"shards: {n} processes ({', '.join(str(c.pid) for c in children)}), lockstep "
                 f"window {w / 1e6:g} ms")
    return step, children


def _stop_shards(children: list[subprocess.Popen]) -> None:
    for child in children:  # a failed run: no shard outlives it
        if child.poll() is None:
            child.terminate()


def _end_shards(children: list, timeout_s: float = 60.0) -> list[str]:
    """Wait for the shards to end; one line for each that failed, saying why."""
    failed = []
    for k, child in enumerate(children):
        try:
            child.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        if child.returncode != 0:
            child.log.seek(0)
            tail = child.log.read().strip().splitlines()[-3:]
            failed.append(f"shard {k} (pid {child.pid}) ended with exit code {child.returncode}"
                          + (f": {' | '.join(tail)}" if tail else ""))
    return failed


def _compare_model(args: argparse.Namespace, record: Path, ok: bool) -> int:
    """The same run with the Python programs; the first frame where the two differ."""
    import subprocess

    from recordings.reader import read_frames

    from .compare import describe_frame, first_divergence

    model_path = record.with_name(record.stem + "-model.mcap")
    argv = [sys.executable, "-m", "hexbench", "run", args.scenario, "--planner", args.planner,
            "--clock", "virtual", "--program", "model", "--record", str(model_path),
            "--timing", args.timing, "--isolated"]
    argv += [] if args.seed is None else ["--seed", str(args.seed)]
    argv += [] if args.profile is None else ["--profile", args.profile]
    for f in getattr(args, "fault", []):
        argv += ["--fault", f]
    print("compare: the same run with the Python programs ...", flush=True)
    model = subprocess.run(argv, capture_output=True, text=True)
    if not model_path.exists():
        raise UsageError(f"the model run failed: {(model.stderr or model.stdout).strip()[-300:]}")
    total, d = first_divergence(read_frames(model_path), read_frames(record))
    if d is None:
        print(f"compare: firmware and model agree on all {total} frames (bytes and sim times); "
              f"model run in {model_path}", flush=True)
        return 0 if ok else 1
    print(f"compare: first difference at frame {d.index + 1} of {total}", flush=True)
    print(f"  model:    {describe_frame(d.expected) if d.expected else '(no more frames)'}", flush=True)
    print(f"  firmware: {describe_frame(d.got) if d.got else '(no more frames)'}", flush=True)
    return 1

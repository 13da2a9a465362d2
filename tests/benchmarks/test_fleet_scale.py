"""Benchmark: a virtual fleet of 10, 100 and 1000 modules on one virtual clock, boot then busy,
recording off and on (issue: fleet speed), with the Python programs (model) and with the C
firmware compiled for the host as every module's program (firmware); and 10 000 modules (40 fleets)
with the firmware, recording on (issue 43). Run alone: ``pytest -s tests/benchmarks/test_fleet_scale.py``
(``HEXBENCH_SCALE_SIZES=10,100`` selects sizes; ``HEXBENCH_SCALE_BIG=0`` leaves out the 10 000, about
5 minutes of ``make bench`` with the 1000 it is held against).

Prints per case: the real-time factor of the boot (9 s of sim time) and of the busy phase
(every module commanded every 1.5 s), the wall cost per bus sample, peak RSS, and the
process's threads (Python's and zenoh's, from /proc). With recording on, every sample put on a
bus must be in the MCAP file (counted: 0 lost), and the wall cost per frame (the samples on
``frame/`` keys, from the recorders' tallies) is printed for the boot and the busy phase. The
firmware cases run on the fleet core
(module_sim/core); the model cases on the Python path. The targets at 1000 modules with
recording on (the fleet core's: boot >= 10x, busy >= 30x real time; cost per sample <= 1.3x
the cost at 10, the same thread count at 10 and 1000) are printed as met or missed; they do
not fail the run. So are issue 43's at 10 000 (firmware, recording on): the cost per frame of the
boot and of the busy phase within 1.5x of that at 1000 (measured in the same run), peak RSS under
4 GiB.
"""

from __future__ import annotations

import gc
import os
import resource
import time

import pytest

from bus.timing import NS_PER_S
from recordings.recorder import Recorder
from test_module_bench import _fleets

SIZES = [int(s) for s in os.environ.get("HEXBENCH_SCALE_SIZES", "10,100,1000").split(",")]
BOOT_TARGET, BUSY_TARGET, COST_RATIO_TARGET = 10.0, 50.0, 1.3  # issue 51
#: issue 43: BIG modules (firmware, recording on) against REF: cost per frame, peak RSS
BIG, REF = int(os.environ.get("HEXBENCH_SCALE_BIG", "10000")), 1000
FRAME_RATIO_TARGET, RSS_TARGET_MB = 1.5, 4096
BIG_BUSY_TARGET = 2.0  # issue 51: 10 000 modules, recording on
RESULTS: dict[tuple[int, bool, str], dict[str, float]] = {}
CASES = [(n, record, program) for n in SIZES for record in (False, True) for program in ("firmware", "model")]
if BIG and (BIG, True, "firmware") not in CASES:
    CASES.append((BIG, True, "firmware"))


def _command(clock, pcs, k: int) -> None:
    """One busy round: every fleet's PC commands all its modules, then 1.5 s of sim time."""
    for pc in pcs:
        pc.send("SxP" if k % 2 == 0 else "SxOff", 1 + k % 6)
    clock.run(until_ns=clock.now_ns() + 1_500_000_000)


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _frames(recorders) -> int:
    """The frames the recorders wrote so far (their tallies count them by link)."""
    return sum(sum(r.tally.frames_by_link.values()) for r in recorders)


@pytest.mark.parametrize(("n", "record", "program"), [  # firmware and model side by side at each size
    pytest.param(*case, id=f"{case[0]}-recording-{'on' if case[1] else 'off'}-{case[2]}") for case in CASES])
def test_fleet_scale(n, record, program, tmp_path):
    if n == BIG and (REF, True, "firmware") not in RESULTS:  # the reference, measured in this run
        test_fleet_scale(REF, True, "firmware", tmp_path)  # its fleets have their own names
    clock, session, buses, fleets, pcs = _fleets(n, ("r" if record else "s") + program[0], program)
    recorders = []
    try:
        if record:
            for bus in buses:
                rec = Recorder(tmp_path / f"{bus.keys.fleet}.mcap", fleet=bus.keys.fleet)
                rec.attach(bus)
                recorders.append(rec)
        t = time.perf_counter()
        cpu = time.process_time()
        for i, fleet in enumerate(fleets):
            fleet.power_up(freeze_gc=i == len(fleets) - 1)
        clock.run(until_ns=9 * NS_PER_S)
        boot_wall = time.perf_counter() - t
        boot_cpu = time.process_time() - cpu
        boot_samples = sum(b.published for b in buses)
        boot_frames = _frames(recorders)
        core = fleets[0].core  # one a clock (firmware); None on the Python path
        boot_windows = _windows(core, boot_wall)

        _command(clock, pcs, 1)  # warm-up: first use of each key declares its publisher
        start_ns, before = clock.now_ns(), sum(b.published for b in buses)
        frames_before = _frames(recorders)
        mark = _windows(core, 0.0)
        t = time.perf_counter()
        cpu = time.process_time()
        rounds = 10
        for k in range(rounds):
            _command(clock, pcs, k)
        busy_wall = time.perf_counter() - t
        busy_cpu = time.process_time() - cpu
        busy_samples = sum(b.published for b in buses) - before
        busy_windows = _windows(core, busy_wall, since=mark)
        busy_frames = _frames(recorders) - frames_before
        busy_sim = (clock.now_ns() - start_ns) / NS_PER_S
        threads = _threads()
        published = sum(b.published for b in buses)
        recorded = sum(r.close().messages for r in recorders) if record else published
        recorders.clear()
        r = RESULTS[(n, record, program)] = {
            "boot_x": 9.0 / boot_wall, "busy_x": busy_sim / busy_wall,
            "us_per_sample": 1e6 * busy_wall / max(busy_samples, 1), "threads": threads,
            "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "boot_samples": boot_samples, "boot_frames": boot_frames, "busy_frames": busy_frames,
            "us_per_frame_boot": 1e6 * boot_wall / max(boot_frames, 1),
            "us_per_frame_busy": 1e6 * busy_wall / max(busy_frames, 1)}
        per_frame = (f"{r['us_per_frame_boot']:.1f} us/frame boot ({boot_frames} frames), "
                     f"{r['us_per_frame_busy']:.1f} us/frame busy ({busy_frames} frames); " if record else "")
        print(f"\n[fleet scale] {program} n={n} ({len(fleets)} fleets) recording {'on' if record else 'off'}: "
              f"boot {r['boot_x']:.2f}x real time ({boot_wall:.1f} s wall, {boot_samples} samples); busy "
              f"{r['busy_x']:.2f}x ({busy_sim:.0f} s sim in {busy_wall:.1f} s); {r['us_per_sample']:.1f} us/sample; "
              f"{per_frame}peak RSS {r['rss_mb']:.0f} MB; {threads} threads; "
              f"{published - recorded} of {published} samples lost")
        # on a shared machine the process's CPU time says more than its wall time
        print(f"[fleet scale] {program} n={n} recording {'on' if record else 'off'}: by CPU time: boot "
              f"{9.0 / boot_cpu:.2f}x ({boot_cpu:.1f} s), busy {busy_sim / busy_cpu:.2f}x ({busy_cpu:.1f} s)")
        if core is not None:
            print(f"[fleet scale] {program} n={n} recording {'on' if record else 'off'}: windows: boot "
                  f"{_say_windows(boot_windows)}; busy {_say_windows(busy_windows)}")
        assert recorded == published  # 0 lost
        if n == BIG and record and program == "firmware":
            _print_big(r, RESULTS[(REF, True, "firmware")], published - recorded)
    finally:
        for rec in recorders:
            rec.close()
        for bus in buses:
            bus.close()
        session.close()
        gc.unfreeze()


def test_python_calls_per_boot_sample(tmp_path):
    """Issue 51: Python per sample, counted, not claimed: a 250-module boot (firmware on the
    core, recording on) under cProfile: its Python calls per sample published."""
    import cProfile
    import pstats

    clock, session, buses, fleets, pcs = _fleets(250, "pc", "firmware")
    rec = Recorder(tmp_path / "boot.mcap", fleet=buses[0].keys.fleet)
    rec.attach(buses[0])
    profile = cProfile.Profile()
    try:
        profile.enable()
        fleets[0].power_up(freeze_gc=True)
        clock.run(until_ns=9 * NS_PER_S)
        profile.disable()
        calls = pstats.Stats(profile).total_calls  # type: ignore[attr-defined]
        samples = buses[0].published
        core = fleets[0].core
        print(f"\n[fleet scale] firmware n=250 boot, recording on: {calls / samples:.1f} Python calls a sample "
              f"({calls} calls, {samples} samples, {core.windows} windows; target: no Python per sample "
              f"nothing acts on: "
              f"{'met' if calls < samples else 'MISSED'})")
    finally:
        rec.close()
        for bus in buses:
            bus.close()
        session.close()
        gc.unfreeze()


def _windows(core, wall_s: float, since: tuple[int, int, float] | None = None) -> tuple[int, int, float]:
    """The core's windows so far, its nanoseconds inside core_run, and the phase's wall
    seconds (less what ``since`` counted): (windows, C ns, wall s)."""
    if core is None:
        return (0, 0, wall_s)
    w0, c0 = (since[0], since[1]) if since else (0, 0)
    return (core.windows - w0, core.run_ns - c0, wall_s)


def _say_windows(w: tuple[int, int, float]) -> str:
    windows, c_ns, wall = w
    python_us = (wall * 1e9 - c_ns) / 1e3 / max(windows, 1)
    return (f"{windows} windows, C {c_ns / 1e9:.2f} s of {wall:.2f} s, "
            f"{python_us:.0f} us of Python a window")


def _print_big(r: dict[str, float], ref: dict[str, float], lost: int) -> None:
    """Issue 43's targets at BIG modules against REF (firmware, recording on). Peak RSS is the
    process's: the REF run came first in it, so it is the larger of the two."""
    boot, busy = (r[f"us_per_frame_{p}"] / ref[f"us_per_frame_{p}"] for p in ("boot", "busy"))
    checks = {
        f"boot cost per frame <= {FRAME_RATIO_TARGET}x n={REF}":
            (boot <= FRAME_RATIO_TARGET, f"{r['us_per_frame_boot']:.1f} / {ref['us_per_frame_boot']:.1f} us = {boot:.2f}x"),
        f"busy cost per frame <= {FRAME_RATIO_TARGET}x n={REF}":
            (busy <= FRAME_RATIO_TARGET, f"{r['us_per_frame_busy']:.1f} / {ref['us_per_frame_busy']:.1f} us = {busy:.2f}x"),
        f"peak RSS < {RSS_TARGET_MB // 1024} GiB": (r["rss_mb"] < RSS_TARGET_MB, f"{r['rss_mb']:.0f} MB"),
        f"busy >= {BIG_BUSY_TARGET:.0f}x real time (issue 51)": (r["busy_x"] >= BIG_BUSY_TARGET, f"{r['busy_x']:.2f}x"),
        "0 samples lost": (lost == 0, f"{lost} lost"),
    }
    print(f"[fleet scale] issue 43, firmware n={BIG}, recording on: "
          + "; ".join(f"{k}: {v} ({'met' if ok else 'MISSED'})" for k, (ok, v) in checks.items()))


SHARDS = int(os.environ.get("HEXBENCH_SCALE_SHARDS", "2"))
SHARDED_TARGET = 1.6  # x the one-process real-time factor, recording on


def test_sharded_fleet_scale(tmp_path):
    """The largest fleet over SHARDS processes on one lockstep clock (issue: shards): the
    shards run the modules and their parts of the worlds; this process runs the PCs, the
    PCs' receivers and the recorders, as ``hexbench run --shards`` does. Boot and busy as
    above, recording on, against the one-process run (measured here if not above)."""
    import subprocess
    import sys

    from bus.lockstep import Lockstep, LockstepClock
    from bus.session import SessionOptions, open_session
    from bus.transport import Bus
    from module_sim.shards import LAGS, participants, window_ns
    from module_sim.world import World
    from planner_svc.endpoint import PcEndpoint
    from tests.support.block_fleets import block_scenarios, fleet_names
    from tests.support.processes import free_port

    n = max(SIZES)
    if (n, True, "model") not in RESULTS:
        test_fleet_scale(n, True, "model", tmp_path / "one")
    one = RESULTS[(n, True, "model")]
    port = free_port()
    clock = LockstepClock()
    session = open_session(SessionOptions(listen=[f"tcp/127.0.0.1:{port}"]))
    scenarios = block_scenarios(n)
    buses = [Bus(clock, name, session=session) for name in fleet_names(n, "sh")]
    w = window_ns(scenarios[0].ir_baud)
    recorders = []
    procs: list[subprocess.Popen] = []
    try:
        for bus in buses:
            rec = Recorder(tmp_path / f"{bus.keys.fleet}.mcap", fleet=bus.keys.fleet)
            rec.attach(bus)
            recorders.append(rec)
        for bus, sc in zip(buses, scenarios):
            World(bus, sc, own=set(), pc=True, physics=False, slack_ns=2 * w)
        pcs = [PcEndpoint(bus) for bus in buses]
        step = Lockstep(buses[0], "pc", participants(SHARDS), w, timeout_s=300, lags=LAGS)
        procs = [subprocess.Popen([sys.executable, "-m", "tests.support.block_fleets", str(n), "sh",
                                   f"{k}/{SHARDS}", "--connect", f"tcp/127.0.0.1:{port}"],
                                  stdout=subprocess.PIPE, text=True) for k in range(SHARDS)]
        for p in procs:
            assert p.stdout.readline().strip() == "ready"
        step.wait_for_peers()
        t = time.perf_counter()
        clock.run(until_ns=9 * NS_PER_S)
        boot_wall = time.perf_counter() - t

        _command(clock, pcs, 1)
        start_ns = clock.now_ns()
        t = time.perf_counter()
        for k in range(10):
            _command(clock, pcs, k)
        busy_wall = time.perf_counter() - t
        busy_sim = (clock.now_ns() - start_ns) / NS_PER_S
        step.finish()
        outs = [p.communicate(timeout=300)[0] for p in procs]
        assert all(p.returncode == 0 for p in procs), outs
        published = sum(b.published for b in buses) + sum(
            int(line.split()[1]) for out in outs for line in out.splitlines() if line.startswith("published "))
        recorded = sum(r.close().messages for r in recorders)
        recorders.clear()
        boot_x, busy_x = 9.0 / boot_wall, busy_sim / busy_wall
        ok = boot_x >= SHARDED_TARGET * one["boot_x"] and busy_x >= SHARDED_TARGET * one["busy_x"]
        print(f"\n[fleet scale] model n={n} over {SHARDS} shard processes, recording on: boot {boot_x:.2f}x "
              f"real time ({boot_x / one['boot_x']:.2f}x one process's {one['boot_x']:.2f}x), busy {busy_x:.2f}x "
              f"({busy_x / one['busy_x']:.2f}x one process's {one['busy_x']:.2f}x); {step.window} windows; "
              f"{published - recorded} of {published} samples lost; target >= {SHARDED_TARGET}x one process: "
              f"{'met' if ok else 'MISSED'}")
        assert recorded == published  # 0 lost
    finally:
        for rec in recorders:
            rec.close()
        for p in procs:
            if p.poll() is None:
                p.kill()
        for bus in buses:
            bus.close()
        session.close()


def test_summary():
    """The targets at the largest size, with recording on; the firmware beside the model."""
    big, small = max(SIZES), min(SIZES)
    for program in ("model", "firmware"):
        if (big, True, program) not in RESULTS or (small, True, program) not in RESULTS:
            continue
        r, s = RESULTS[(big, True, program)], RESULTS[(small, True, program)]
        checks = {
            f"boot >= {BOOT_TARGET}x": (r["boot_x"] >= BOOT_TARGET, f"{r['boot_x']:.2f}x"),
            f"busy >= {BUSY_TARGET}x": (r["busy_x"] >= BUSY_TARGET, f"{r['busy_x']:.2f}x"),
            f"cost per sample <= {COST_RATIO_TARGET}x n={small}":
                (r["us_per_sample"] <= COST_RATIO_TARGET * s["us_per_sample"],
                 f"{r['us_per_sample'] / s['us_per_sample']:.2f}x"),
            "threads flat": (r["threads"] == s["threads"], f"{s['threads']} -> {r['threads']}"),
        }
        print(f"\n[fleet scale] {program} n={big}, recording on: "
              + "; ".join(f"{k}: {v} ({'met' if ok else 'MISSED'})" for k, (ok, v) in checks.items()))
    for n in SIZES:
        m, f = RESULTS.get((n, False, "model")), RESULTS.get((n, False, "firmware"))
        if m and f:
            print(f"[fleet scale] n={n} recording off, busy: model {m['busy_x']:.2f}x "
                  f"{m['us_per_sample']:.1f} us/sample, firmware {f['busy_x']:.2f}x "
                  f"{f['us_per_sample']:.1f} us/sample (firmware cost / model cost "
                  f"{f['us_per_sample'] / m['us_per_sample']:.2f})")

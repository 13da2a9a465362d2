"""``make demo`` / ``hexbench demo``: thesis-6 end to end, recorded and replayed.

Runs the six-module example of thesis Ch. 4 on virtual modules with the thesis planner
(bring-up, localization, eight moves, each verified against the world), records every
frame to ``thesis-6.mcap``, replays it to ``thesis-6.rrd`` (in ``--out``, by default the
working directory) and says how to open both.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path


def _tool(name: str) -> str:
    """How to call one of this environment's commands from here (``.venv/bin/rerun``)."""
    path = Path(sys.executable).parent / name
    return os.path.relpath(path) if path.exists() else name


def run_demo(args: argparse.Namespace) -> int:
    from recordings.replay import replay

    from .run import add_run_arguments, cmd_run

    out = Path(getattr(args, "out", None) or ".")
    out.mkdir(parents=True, exist_ok=True)
    mcap, rrd = out / "thesis-6.mcap", out / "thesis-6.rrd"
    print(f"== hexbench run thesis-6 --planner thesis-serial --clock virtual --record {mcap}",
          flush=True)
    run = argparse.ArgumentParser(prog="hexbench run")
    add_run_arguments(run, with_fleet=True)
    code = cmd_run(run.parse_args(["thesis-6", "--planner", "thesis-serial", "--clock", "virtual",
                                   "--record", str(mcap)]))
    if code != 0:
        print(f"demo: the run failed (exit {code}); the recording {mcap} shows why")
        return code
    print(f"== hexbench replay {mcap} --rrd {rrd}", flush=True)
    st = replay(mcap, rrd=rrd)
    print(f"replayed {st.frames} frames, {st.sim_ns / 1e9:.1f} sim s in {st.wall_s:.1f} s "
          f"({st.speed:.0f}x real time)")
    print("\nopen them with:\n"
          f"  {_tool('rerun')} {rrd}        # the replay: hexagons, actuators, IR, frames\n"
          f"  {_tool('hexbench')} info {mcap}    # frames per link, errors and expected events, metadata\n"
          f"  {_tool('rerun')} {mcap}       # rerun's own MCAP importer\n"
          f"  Foxglove: Open local file -> {mcap.resolve()}\n"
          "            a 3D panel on foxglove/scene (frame 'lattice'), a Log panel on foxglove/log\n"
          "watch a run as it goes:\n"
          f"  {_tool('hexbench')} run thesis-6 --clock wall --live rerun       # a rerun viewer\n"
          f"  {_tool('hexbench')} run thesis-6 --clock wall --live foxglove    # Foxglove: Open connection -> "
          "ws://127.0.0.1:8765")
    return 0

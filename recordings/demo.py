"""``make demo`` / ``hexbench demo``: thesis-6 end to end, recorded and replayed.

Runs the six-module example of thesis Ch. 4 on virtual modules with the thesis planner
(bring-up, localization, eight moves, each verified against the world), records every
frame to ``recordings/thesis-6.mcap``, replays it to ``recordings/thesis-6.rrd`` and says
how to open both.
"""

from __future__ import annotations

import argparse
from pathlib import Path

OUT = Path(__file__).resolve().parent


def run_demo(args: argparse.Namespace) -> int:
    from bus.cli import main

    from .replay import replay

    out = Path(getattr(args, "out", None) or OUT)
    out.mkdir(parents=True, exist_ok=True)
    mcap, rrd = out / "thesis-6.mcap", out / "thesis-6.rrd"
    print(f"== hexbench run thesis-6 --planner thesis-serial --clock virtual --record {mcap}",
          flush=True)
    code = main(["run", "thesis-6", "--planner", "thesis-serial", "--clock", "virtual",
                 "--record", str(mcap)])
    if code != 0:
        print(f"demo: the run failed (exit {code}); the recording {mcap} shows why")
        return code
    print(f"== hexbench replay {mcap} --rrd {rrd}", flush=True)
    st = replay(mcap, rrd=rrd)
    print(f"replayed {st.frames} frames, {st.sim_ns / 1e9:.1f} sim s in {st.wall_s:.1f} s "
          f"({st.speed:.0f}x real time)")
    print("\nopen them with:\n"
          f"  .venv/bin/rerun {rrd}                 # the replay: hexagons, actuators, IR, frames\n"
          f"  .venv/bin/hexbench info {mcap}        # frames per link, events, metadata\n"
          f"  .venv/bin/rerun {mcap}                # rerun's own MCAP importer\n"
          f"  (or open {mcap.name} in Foxglove)")
    return 0

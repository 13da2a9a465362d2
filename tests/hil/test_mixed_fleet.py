"""A mixed fleet (issue: hardware in the loop): a virtual module behind a real pty plays the
hardware; ``hexbench run`` bridges it, drives it with the virtual one, and records it."""

from __future__ import annotations

import json

from mcap.reader import make_reader

from hexbench.cli import main
from hexbench.standin import StandIn


def test_planner_run_with_a_real_module_reaches_the_goal(tmp_path, capsys):
    standin = StandIn.on_pty(module_id=2, profile="v2").start()
    try:
        scenario = tmp_path / "mixed.toml"
        scenario.write_text(
            'name = "mixed-pair"\nprofile = "v2"\nfixed = [0, 0]\ngoal = [[0, 0], [0, 1]]\n'
            "[[modules]]\nid = 1\ncell = [0, 0]\n"
            f'[[modules]]\nid = 2\ncell = [1, 0]\nkind = "real"\nport = "{standin.path}"\n')
        mcap = tmp_path / "mixed.mcap"
        code = main(["run", str(scenario), "--planner", "thesis-serial", "--clock", "wall",
                     "--record", str(mcap), "--isolated", "--fleet", "mixed"])
        out = capsys.readouterr().out
    finally:
        standin.close()
    assert code == 0, out
    assert "thesis-serial: goal reached" in out and "moves 1 " in out
    assert "m2 (real) could not be localized: taking its pose (1,0)" in out

    serial, confirmed, virtual_sources = [], [], set()
    with open(mcap, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            d = json.loads(message.data)
            if channel.topic.startswith("frame/"):
                if d.get("origin") == "serial":
                    serial.append(d)
                else:
                    virtual_sources.add(d["src"])
            elif channel.topic == "world/event" and d["kind"] == "move-confirmed":
                confirmed.append(d)
    # the real module's answers came through the bridge, and only through it
    assert serial and all(d["src"].startswith("hil.") for d in serial)
    kinds = {d["kind"] for d in serial}
    assert {"position", "ack"} <= kinds
    assert not any(s.startswith("m2.") for s in virtual_sources)
    (ev,) = confirmed
    assert ev["module"] == "m2" and ev["data"]["to"] == [0, 1]

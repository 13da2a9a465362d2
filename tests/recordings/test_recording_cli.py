"""``hexbench info`` over a recording."""

from __future__ import annotations

import json

from hexbench.cli import main


def test_info_json_counts(recorded, capsys):
    assert main(["info", str(recorded.path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames_by_link"] == recorded.published.frames_by_link()
    assert info["complete"] is True
    assert info["noise"] == sum(1 for e in recorded.published.frames if e.kind == "noise") > 0
    assert info["faults"] == 1
    assert info["errors"] == recorded.tally.errors > 0
    assert info["metadata"]["scenario"] == "synthetic"
    assert info["duration_s"] == recorded.published.end_ns / 1e9


def _sections(text: str) -> dict[str, list[str]]:
    """``hexbench info``'s text by heading: each ``name:`` line's rest, then its indented lines."""
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        if line.startswith("  "):
            out[head].append(line.strip())
        else:
            head, rest = line.split(":", 1)
            out.setdefault(head, []).append(rest.strip())
    return out


def test_info_text(recorded, capsys):
    """Every figure info prints is the one the run published (or the file holds)."""
    from collections import Counter

    from recordings.reader import iter_samples

    published = recorded.published
    assert main(["info", str(recorded.path)]) == 0
    info = _sections(capsys.readouterr().out)
    assert info["file"] == [str(recorded.path)]
    assert info["state"] == ["complete"]
    assert info["duration"] == [f"{published.end_ns / 1e9:.3f} s  ({recorded.tally.messages} samples, "
                                "compression zstd)"]
    noise = Counter(e.link for e in published.frames if e.kind == "noise")
    faults = sum(1 for topic, r in published.records if topic == "world/event" and r.kind == "fault")
    frames, *links = info["frames"]
    assert frames == (f"{len(published.frames)}  noise {sum(noise.values())}  errors {recorded.tally.errors}  "
                      f"faults {faults}")
    assert links == [f"{link:12} {n:8}" + (f"  ({noise[link]} noise)" if noise[link] else "")
                     for link, n in sorted(published.frames_by_link().items())]
    assert info["errors"] == [", ".join(f"{k} {n}" for k, n in sorted(recorded.tally.errors_by_kind.items()))]
    world = Counter(r.kind for topic, r in published.records if topic == "world/event")
    assert info["world"] == [", ".join(f"{k} {n}" for k, n in sorted(world.items()))]
    metadata = dict(line.split(None, 1) for line in info["metadata"][1:])
    assert (metadata["scenario"], metadata["seed"], metadata["fleet"]) == ("synthetic", "1", "rectest")
    # every channel, with its schema and as many messages as the file holds on it
    held = Counter(s.topic for s in iter_samples(recorded.path, derived=True))
    count, *channels = info["channels"]
    assert int(count) == len(held) == len(channels)
    assert {line.split()[0]: int(line.split()[2]) for line in channels} == held
    assert {line.split()[0]: line.split()[1] for line in channels if line.startswith(("frame/", "world/pose/"))
            } == {t: "hexbot.Frame" if t.startswith("frame/") else "hexbot.Pose"
                  for t in held if t.startswith(("frame/", "world/pose/"))}


def test_info_missing_file(tmp_path, capsys):
    assert main(["info", str(tmp_path / "nope.mcap")]) == 2
    assert "no recording" in capsys.readouterr().err


def test_info_tells_expected_events_from_errors(tmp_path, capsys):
    """A healthy pair run makes overruns (the boot handshake's 'R's) and collisions (boot
    banners, and the answers to the first Select, which every module still acknowledges):
    info counts them as expected, each with its reason, and finds no error."""
    out = tmp_path / "pair.mcap"
    assert main(["run", "pair", "--planner", "thesis-serial", "--clock", "virtual",
                 "--record", str(out)]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    expected = {line.split()[1]: int(line.split()[2]) for line in text.splitlines() if line.startswith("expected:")}
    assert expected["boot-handshake"] > 0 and expected["all-answer"] > 0
    assert "boot handshake" in text and "every module answers every command" in text
    frames_line = next(line for line in text.splitlines() if line.startswith("frames:"))
    assert f"errors 0 (and {sum(expected.values())} expected)" in frames_line
    assert "errors:     none" in text
    assert main(["info", str(out), "--json"]) == 0
    health = json.loads(capsys.readouterr().out)["health"]
    assert health == {"errors": {}, "expected": dict(sorted(expected.items()))}


def test_what_makes_an_event_an_error():
    from recordings.health import PcTimeline, reason
    pc = PcTimeline(first_command_ns=9_000, all_answer_until_ns=10_000)
    assert reason({"kind": "uart-overrun", "uart": "uart0", "lost": 0x52, "sim_time_ns": 5}, pc) == "boot-handshake"
    assert reason({"kind": "uart-overrun", "uart": "uart0", "lost": 0x2A, "sim_time_ns": 5}, pc) is None
    assert reason({"kind": "uart-overrun", "uart": "uart1", "lost": 1, "channel": 3, "sim_time_ns": 50_000}, pc) == "side-light"
    assert reason({"kind": "uart-overrun", "uart": "uart1", "lost": 1, "channel": 0, "sim_time_ns": 50_000}, pc) is None
    assert reason({"kind": "uart-overrun", "uart": "uart1", "lost": 1, "sim_time_ns": 50_000}, pc) is None  # old files
    assert reason({"kind": "collision", "receiver": "m3", "sim_time_ns": 8_000}, pc) == "boot-banners"
    assert reason({"kind": "collision", "receiver": "m3", "sim_time_ns": 9_500}, pc) is None
    assert reason({"kind": "collision", "receiver": "pc", "sim_time_ns": 9_500}, pc) == "all-answer"
    assert reason({"kind": "rx-noise", "src": "pc", "sim_time_ns": 10_000}, pc) == "all-answer"
    assert reason({"kind": "rx-noise", "src": "pc", "sim_time_ns": 10_001}, pc) is None  # data lost
    assert reason({"kind": "rx-noise", "src": "pc", "sim_time_ns": 10**12}, PcTimeline(9_000, None)) == "all-answer"
    assert reason({"kind": "timeout", "src": "pc", "sim_time_ns": 1}, pc) is None


def test_info_counts_the_channels_the_recorder_derives_for_foxglove(recorded, capsys):
    """``foxglove/scene`` and ``foxglove/log`` are not bus samples (not in the tally), but
    their messages are in the file: info counts them as the file holds them."""
    from collections import Counter

    from recordings.reader import iter_samples
    from recordings.schemas import LOG_TOPIC, SCENE_TOPIC

    held = Counter(s.topic for s in iter_samples(recorded.path, [SCENE_TOPIC, LOG_TOPIC]))
    assert held[SCENE_TOPIC] > 0 and held[LOG_TOPIC] == sum(recorded.tally.frames_by_link.values())
    assert main(["info", str(recorded.path)]) == 0
    counts = {line.split()[0]: int(line.split()[-1]) for line in capsys.readouterr().out.splitlines()
              if line.startswith("  foxglove/")}
    assert counts == held
    assert main(["info", str(recorded.path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["derived_by_topic"] == dict(sorted(held.items()))
    assert info["messages"] == recorded.tally.messages  # the tally stays the bus's samples

"""``--live foxglove``: a wall-clock run served on a Foxglove WebSocket, read by a WebSocket
client from PyPI (``websockets``) speaking Foxglove's protocol on loopback, as the app does."""

from __future__ import annotations

import asyncio
import base64
import json
import struct
import time
from typing import Callable

import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from processes import free_port, hexbench, wall_fleet
from recordings.foxglove import module_cells
from toolchain import module

websockets = module("websockets")

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


async def _scenes(url: str, deadline: float, enough: Callable[[dict[str, tuple[int, int]]], bool]
                  ) -> tuple[dict, dict, dict[str, tuple[int, int]]]:
    """Subscribe to the scene as the Foxglove app does and read scene messages until the module
    cells seen so far are ``enough``: (serverInfo, the scene's advertisement, the cells)."""
    while True:  # the server starts with the run: try until it listens
        try:
            ws = await websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    async with ws:
        info: dict = {}
        channels: dict[int, dict] = {}
        scene: dict | None = None
        decode = None
        cells: dict[str, tuple[int, int]] = {}
        while time.monotonic() < deadline:
            try:
                msg = await asyncio.wait_for(ws.recv(), timeout=max(0.1, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                break
            if isinstance(msg, str):
                d = json.loads(msg)
                if d["op"] == "serverInfo":
                    info = d
                elif d["op"] == "advertise":
                    for ch in d["channels"]:
                        channels[ch["id"]] = ch
                if scene is None:
                    scene = next((c for c in channels.values() if c["topic"] == "foxglove/scene"), None)
                    if scene is not None:
                        schema = Schema(id=1, name=scene["schemaName"], encoding="protobuf",
                                        data=base64.b64decode(scene["schema"]))
                        decode = DecoderFactory().decoder_for("protobuf", schema)
                        await ws.send(json.dumps({"op": "subscribe",
                                                  "subscriptions": [{"id": 1, "channelId": scene["id"]}]}))
            elif msg[0] == 0x01:  # message data: opcode, subscription id (u32), log time (u64), payload
                sub, _ = struct.unpack_from("<IQ", msg, 1)
                assert sub == 1 and decode is not None
                cells.update(module_cells(decode(bytes(msg[13:]))))
                if enough(cells):
                    return info, scene, cells
    raise AssertionError(f"scene not complete before the deadline: cells {cells}; "
                         f"channels {sorted(c['topic'] for c in channels.values())}")


def _served_url(proc) -> str:
    """The WebSocket URL the process says it serves (port 0: the kernel chose a free one)."""
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.startswith("live: Foxglove WebSocket on "):
            return line.split(" on ", 1)[1].split()[0]
    raise AssertionError("the process ended without serving: " + "".join(seen))


def _watch(proc, enough, seconds: float = 60):
    try:
        return asyncio.run(_scenes(_served_url(proc), time.monotonic() + seconds, enough))
    except (OSError, AssertionError) as exc:
        proc.kill()
        raise AssertionError(f"{exc}\n{proc.communicate(timeout=30)[0]}") from None


@pytest.mark.wall_clock
def test_a_wall_clock_run_is_served_to_foxglove():
    port = free_port()
    proc = hexbench("run", "thesis-6", "--clock", "wall", "--live", "foxglove=127.0.0.1:0",
                    "--listen", f"tcp/127.0.0.1:{port}", "--fleet", f"fox{port}")
    try:
        info, scene, cells = _watch(proc, lambda c: len(c) == 6)
    finally:
        proc.terminate()
        out = proc.communicate(timeout=30)[0]
    assert info.get("name") == "hexbench", out
    assert scene["schemaName"] == "foxglove.SceneUpdate" and scene["encoding"] == "protobuf"
    assert set(cells) == {f"m{i}" for i in range(1, 7)}


def _pose(module: str, x: int, y: int) -> bytes:
    return json.dumps({"module": module, "id": int(module[1:]), "x": x, "y": y, "orientation": 0,
                       "sim_time_ns": 0, "kind": "virtual", "fixed": False, "type": "pose"}).encode()


async def _first_words(url: str, live, poses: dict[str, tuple[int, int]]) -> tuple[list[str], dict, list[str]]:
    """Connect before any sample, subscribe to the scene as soon as it is advertised, then feed
    ``poses``: (the topics of the first advertisement, the cells the scene showed, every status
    message the server sent)."""
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        first: list[str] = []
        statuses: list[str] = []
        cells: dict[str, tuple[int, int]] = {}
        decode = None
        while len(cells) < len(poses):
            try:  # before the fix nothing was advertised until the first sample
                msg = await asyncio.wait_for(ws.recv(), timeout=20)
            except asyncio.TimeoutError:
                break
            if isinstance(msg, str):
                d = json.loads(msg)
                if d["op"] == "status":
                    statuses.append(d["message"])
                elif d["op"] == "advertise" and not first:
                    first = [c["topic"] for c in d["channels"]]
                    scene = next(c for c in d["channels"] if c["topic"] == "foxglove/scene")
                    decode = DecoderFactory().decoder_for("protobuf", Schema(
                        id=1, name=scene["schemaName"], encoding="protobuf", data=base64.b64decode(scene["schema"])))
                    await ws.send(json.dumps({"op": "subscribe",
                                              "subscriptions": [{"id": 1, "channelId": scene["id"]}]}))
                    for m, (x, y) in poses.items():  # the run starts once the viewer is there
                        live.on_sample(live.keys.pose(m), _pose(m, x, y))
            elif msg[0] == 0x01 and decode is not None:
                cells.update(module_cells(decode(bytes(msg[13:]))))
    return first, cells, statuses


def test_a_viewer_there_before_the_run_hears_of_the_scene_at_once_and_is_never_refused():
    """The scene and the log are channels from the start: a viewer connected before the first
    sample learns of them in its first advertisement, which the SDK records before it reads the
    viewer's subscription (a channel made later is advertised before it is recorded, and a
    subscription in between is refused: "unknown channel", no scene at all)."""
    from recordings.live_foxglove import LiveFoxglove

    poses = {"m1": (0, 0), "m2": (1, 0), "m3": (2, 0)}
    with LiveFoxglove(fleet="early", port=0, start_ns=1_000_000_000) as live:
        first, cells, statuses = asyncio.run(_first_words(live.url, live, poses))
    assert {"foxglove/scene", "foxglove/log"} <= set(first)
    assert cells == poses and statuses == []


def test_a_bad_live_spec_is_refused_in_one_line(capsys):
    from hexbench.cli import main
    with pytest.raises(SystemExit) as exc:
        main(["run", "pair", "--live", "foxglove=nowhere"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "foxglove=HOST:PORT" in err and "Traceback" not in err


@pytest.mark.wall_clock
def test_monitor_serves_a_fleet_in_another_process_to_foxglove():
    """``monitor --live foxglove`` joins late: it asks the world to republish its poses, so the
    scene shows every module of the running fleet."""
    bus_port = free_port()
    fleet = wall_fleet("pair", bus_port, f"mon{bus_port}")
    monitor = hexbench("monitor", "--connect", f"tcp/127.0.0.1:{bus_port}", "--fleet", f"mon{bus_port}",
                       "--live", "foxglove=127.0.0.1:0", "--seconds", "60")
    try:
        _, _, cells = _watch(monitor, lambda c: len(c) == 2, seconds=45)
    finally:
        for p in (monitor, fleet):
            p.terminate()
            p.communicate(timeout=30)
    assert cells == {"m1": (0, 0), "m2": (1, 0)}  # the pair at rest: nobody commands it

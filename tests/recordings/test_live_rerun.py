"""The live rerun view: a virtual run streamed through a real rerun gRPC server while it goes,
drawn by the same code as the .rrd replay (same entities, same module rows)."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import time
import warnings
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from bus.envelope import Envelope
from bus.scenario import load
from hexbench.virtual_run import VirtualRun
from processes import free_port
from recordings.live_rerun import LiveRerun, open_stream
from recordings.player import Player
from recordings.replay import ReplayBuilder, Scene, replay, rerun_binary

FLEET = "livetest"
BOOTED_NS = 9_000_000_000  # both modules of the pair have booted (as conftest.record_pair runs it)
SENTINEL = "test/sent"  # logged after everything else: once the server wrote it, it has it all


# --- reading .rrd files back -------------------------------------------------------------------
def _chunks(path: Path) -> list[Any]:
    with warnings.catch_warnings():  # the server's file has no footer: the reader warns, scans it whole
        warnings.simplefilter("ignore")
        return list(RrdReader(path).stream())


def _times(chunks: list[Any], entity: str, column: str) -> list[int]:
    """The sim times (ns) of the rows of ``entity`` that have ``column``."""
    out: list[int] = []
    for c in chunks:
        if c.entity_path != entity:
            continue
        batch = c.to_record_batch()
        if column in batch.schema.names and "sim_time" in batch.schema.names:
            t = batch.column("sim_time").cast("int64").to_pylist()
            out += [ti for ti, v in zip(t, batch.column(column).to_pylist()) if v is not None]
    return sorted(out)


def _texts(chunks: list[Any], entity: str) -> list[str]:
    return [line for c in chunks if c.entity_path == entity
            for row in c.to_record_batch().column("TextLog:text").to_pylist() if row for line in row]


# --- the server ----------------------------------------------------------------------------------
class RerunServer:
    """``rerun --save FILE``: a gRPC server (the proxy a logging SDK connects to) that streams
    everything it receives to an .rrd file, in a process of its own, on a free loopback port."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.port = free_port()
        self.url = f"rerun+http://127.0.0.1:{self.port}/proxy"
        self.log = out.with_suffix(".log").open("w")
        self.proc = subprocess.Popen([rerun_binary(), "--save", str(out), "--bind", "127.0.0.1",
                                      "--port", str(self.port)],
                                     stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)

    def wait_listening(self, timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise AssertionError(f"rerun exited with {self.proc.returncode}: {self.output()}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                time.sleep(0.05)
        raise AssertionError(f"rerun did not listen on {self.port} within {timeout_s} s: {self.output()}")

    def wait_for(self, entity: str, timeout_s: float = 30.0) -> list[Any]:
        """The chunks of the file once it holds ``entity`` (the file grows as data comes)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.out.exists():
                try:
                    chunks = _chunks(self.out)
                except Exception:  # a message half written: read again
                    chunks = []
                if any(c.entity_path == f"/{entity}" for c in chunks):
                    return chunks
            time.sleep(0.05)
        raise AssertionError(f"{entity} did not reach {self.out} within {timeout_s} s: {self.output()}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)  # its Ctrl-C: stop saving
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=15)
        self.log.close()

    def output(self) -> str:
        self.log.flush()
        return self.out.with_suffix(".log").read_text()[-2000:]


@pytest.fixture
def rerun_server(tmp_path, rerun_bin):
    server = RerunServer(tmp_path / "received.rrd")
    try:
        server.wait_listening()
        yield server
    finally:
        server.stop()


# --- the live run --------------------------------------------------------------------------------
def test_a_virtual_run_streams_to_a_rerun_server(rerun_server, pair_commands, tmp_path):
    """The pair scenario booting and acknowledging commands, with a LiveRerun on its bus next to
    the recorder: the server gets the same entities as the .rrd replay of the recording, and the
    same module rows."""
    t0 = time.perf_counter()
    rec = open_stream(connect=rerun_server.url, recording_id="live-test")
    live = LiveRerun(rec, fleet=FLEET, flush_interval_s=0.05, meta={"scenario": "pair", "seed": 1})
    mcap = tmp_path / "pair.mcap"
    try:
        with VirtualRun(load("pair"), fleet=FLEET, record=mcap, attach=live.attach) as run:
            run.clock.run(until_ns=BOOTED_NS, timeout_s=60)
            # while the run waits: the boot is on the server already, modules drawn
            early = rerun_server.wait_for("world/modules/m2/leds")
            assert _texts(early, "/frames/uart0-up") and not _texts(early, "/frames/pc")
            for command in pair_commands:
                run.pc.ack(*command)
    finally:
        live.close()
    assert live.flush_error is None
    assert live.undecodable == 0 and live.samples > 100 and live.rows > 0
    rec.log(SENTINEL, rr.TextLog("end"), static=True)
    rec.flush(timeout_sec=30)
    rec.disconnect()
    received = rerun_server.wait_for(SENTINEL)
    t_live = time.perf_counter() - t0

    rrd = tmp_path / "replay.rrd"
    replay(mcap, rrd=rrd)
    replayed = _chunks(rrd)
    paths = {c.entity_path for c in received}
    for want in ("/world/modules/m1", "/world/modules/m1/magnets", "/world/modules/m1/joints",
                 "/world/modules/m1/leds", "/world/modules/m1/ir", "/world/modules/m2", "/world/lattice",
                 "/frames/centre", "/frames/pc", "/frames/uart0-up", "/events/bus", "/plots/fps/centre"):
        assert want in paths, want
    assert {c.entity_path for c in replayed} <= paths  # nothing of the replay is missing live
    for m in ("m1", "m2"):
        base = f"/world/modules/{m}"
        live_rows = _times(received, base, "LineStrips2D:strips")
        assert live_rows and live_rows == _times(replayed, base, "LineStrips2D:strips"), m
        assert _times(received, f"{base}/ir", "LineStrips2D:strips") == _times(replayed, f"{base}/ir", "LineStrips2D:strips")
    # every frame, in its link's text log: the PC's commands among them
    assert len(_texts(received, "/frames/pc")) == len(pair_commands)
    assert _texts(received, "/frames/centre") == _texts(replayed, "/frames/centre")
    print(f"live run + stream: {t_live:.2f} s, {live.samples} samples, {live.rows} rows, {live.flushes} flushes")


def test_bad_payloads_are_drawn_as_errors_not_raised(tmp_path):
    out = tmp_path / "bad.rrd"
    rec = rr.RecordingStream("hexbench", recording_id="bad")
    rec.save(out)
    live = LiveRerun(rec, fleet=FLEET, flush_interval_s=0.01)
    key = f"hexbot/{FLEET}"
    pose = {"module": "m1", "id": 1, "x": 0, "y": 0, "orientation": 0, "sim_time_ns": 5}
    bad: list[tuple[Any, Any]] = [
        (f"{key}/world/pose/m1", b"\xff\xfe"), (f"{key}/world/pose/m1", b"{"), (f"{key}/world/pose/m1", b"[1, 2]"),
        (f"{key}/world/pose/m1", json.dumps({**pose, "x": "a"}).encode()),
        (f"{key}/world/pose/m1", json.dumps({**pose, "module": 3}).encode()),
        (f"{key}/world/pose/m1", json.dumps({**pose, "orientation": True}).encode()),
        (f"{key}/planner/state", json.dumps({"sim_time_ns": 6, "step": 1, "planner": "p", "occupied": [[1]],
                                             "goal": []}).encode()),
        (f"{key}/frame/side/m1.comm", b'{"link": "side", "src": "m1.comm"}'),
        (f"{key}/frame/side/m1.comm", json.dumps({"link": "side", "src": "m1.comm", "dst": "*", "raw": "zz",
                                                  "sim_time_ns": 7, "wall_time_ns": 0, "seq": 0}).encode()),
        (f"{key}/world/event", None), (f"{key}/world/event", "text"), (f"{key}/world/event", 12), (None, b"{}"),
    ]
    for k, payload in bad:
        live.on_sample(k, payload)
    live.on_sample(f"{key}/world/pose/m1", json.dumps(pose).encode())  # a good one still draws
    live.close()
    assert live.undecodable == len(bad)
    rec.disconnect()
    chunks = _chunks(out)
    errors = _texts(chunks, "/events/recorder")
    assert len(errors) == len(bad) - 1  # the sample without a key has no topic to be shown under
    assert any("x must be integer" in e for e in errors)
    assert _times(chunks, "/world/modules/m1", "LineStrips2D:strips") == [5]


def test_open_stream_needs_a_viewer():
    with pytest.raises(ValueError):
        open_stream()


# --- the painter: in increments as at once -------------------------------------------------------
def _gather(into: dict[tuple[str, str], list[tuple]], scene: Scene) -> None:
    """Append the module rows of ``scene`` (time, then each field's instances) to ``into``."""
    for (entity, archetype), cols in scene._cols.items():
        if not entity.startswith("world/modules/"):
            continue
        rows = into[(entity, archetype.__name__)]
        start = 0
        names = sorted(cols.fields)
        for t, n in zip(cols.times, cols.lengths):
            rows.append((t, *([np.asarray(v).tolist() for v in cols.fields[f][start:start + n]] for f in names)))
            start += n


@pytest.mark.parametrize("run", ["recorded", "pair_recording"])
@pytest.mark.parametrize("flush_every", [1, 13, 60])
def test_incremental_painting_draws_the_rows_of_a_replay(run, flush_every, request):
    """A recording fed a few samples at a time, painted up to a horizon held back by the longest
    IR frame after each flush, gives the module rows of the one-shot replay, in the same order
    (the synthetic run's m4 moves: animation frames span flushes)."""
    source = request.getfixturevalue(run)
    items = list(Player(source.path if run == "recorded" else source).items())
    whole = ReplayBuilder()
    whole.feed(items)
    expected: dict[tuple[str, str], list[tuple]] = defaultdict(list)
    _gather(expected, whole.render())

    late = max((v.sim_time_ns - v.first_byte_ns for _, _, v in items
                if isinstance(v, Envelope) and v.first_byte_ns is not None), default=0)
    b = ReplayBuilder()
    got: dict[tuple[str, str], list[tuple]] = defaultdict(list)
    flushes = 0
    for i in range(0, len(items), flush_every):
        part = items[i:i + flush_every]
        b.feed(part)
        b.render(part[-1][0] - late)
        _gather(got, b.scene)
        b.scene.clear()
        flushes += 1
    b.render()
    _gather(got, b.scene)
    assert flushes > 1
    assert got.keys() == expected.keys()
    assert got[("world/modules/m1", "LineStrips2D")], "m1 has outlines"
    for key in expected:
        assert got[key] == expected[key], key
    if run == "recorded":  # the moving module's animation frames are in there
        assert len(got[("world/modules/m4", "LineStrips2D")]) > 20


def test_hexbench_run_live_rerun_streams_to_the_server(rerun_server, capsys):
    """The CLI: ``hexbench run pair --live rerun=URL`` sends the module entities to a viewer's
    server as the run goes (read back from what the server saved, once the run has ended)."""
    from hexbench.cli import main
    assert main(["run", "pair", "--clock", "virtual", "--live", f"rerun={rerun_server.url}"]) == 0
    assert f"live: rerun stream to {rerun_server.url}" in capsys.readouterr().out
    chunks = rerun_server.wait_for("world/modules/m2/joints")
    entities = {c.entity_path for c in chunks}
    assert {"/world/modules/m1", "/world/modules/m2", "/world/modules/m1/magnets", "/frames/pc",
            "/planner/goal"} <= entities
    assert any("command Move" in line for line in _texts(chunks, "/frames/pc"))

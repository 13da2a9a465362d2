"""Ports by URL (loop://, socket://), byte times, names, and the CLI's refusals; no stand-in."""

from __future__ import annotations

import itertools
import socket
import threading
from typing import Iterator

import pytest

from hexbench.cli import main
from bus.clock import VirtualClock, WallClock
from bus.codec import EOL, PREAMBLE, encode_command
from bus.envelope import Envelope
from bus.session import SessionOptions
from bus.timing import byte_time_ns
from bus.transport import Bus
from hil.bridge import FAULT, RECOVERED, CentreBridge
from hil.line import ByteTimes
from hil.port import Backoff, port_name
from planner_svc.endpoint import PcEndpoint

_fleets = itertools.count()
B = byte_time_ns(300)


@pytest.fixture
def bus() -> Iterator[Bus]:
    b = Bus(WallClock(), f"hilport{next(_fleets)}", options=SessionOptions(isolated=True))
    yield b
    b.close()


def run_until(bus: Bus, cond, timeout_s: float, what: str) -> None:
    bus.clock.run(until=cond, timeout_s=timeout_s)
    assert cond(), f"timed out after {timeout_s} s waiting for {what}"


@pytest.mark.parametrize("url,name", [
    ("/dev/ttyUSB0", "ttyUSB0"), ("socket://10.0.0.5:7000", "socket-10.0.0.5:7000"),
    ("rfc2217://lab-pi:4001?ign_set_control", "rfc2217-lab-pi:4001"), ("loop://", "loop"),
    ("spy:///dev/ttyS0?file=x.txt", "spy-dev_ttyS0")])
def test_port_names_are_key_chunks(url, name):
    assert port_name(url) == name


def test_received_bytes_are_backdated_from_arrival_and_never_closer_than_the_baud():
    t = ByteTimes(300)
    assert t.ends(3, 10 * B) == [8 * B, 9 * B, 10 * B]
    assert t.ends(2, 10 * B) == [11 * B, 12 * B]  # arrived too fast for the line: paced out


def test_bytes_handed_over_at_once_are_paced_from_their_arrival():
    t = ByteTimes(300)
    assert t.sent(3, 100) == [100, 100 + B, 100 + 2 * B]
    assert t.sent(1, 200) == [100 + 3 * B]


def test_virtual_clock_is_refused():
    vbus = Bus(VirtualClock(), f"hilport{next(_fleets)}", options=SessionOptions(isolated=True))
    try:
        with pytest.raises(ValueError, match="wall clock"):
            CentreBridge(vbus, "loop://")
    finally:
        vbus.close()


def test_cli_refuses_the_virtual_clock_and_bad_urls(capsys):
    assert main(["hil", "--isolated", "--port", "loop://", "--clock", "virtual"]) == 2
    assert "--clock virtual is not possible with real hardware" in capsys.readouterr().err
    assert main(["hil", "--isolated", "--port", "nope://x"]) == 2
    assert "protocol 'nope' not known" in capsys.readouterr().err
    assert main(["hil", "--isolated"]) == 2
    assert "nothing to bridge" in capsys.readouterr().err


def test_loop_url_carries_the_pc_light_back_as_hardware_frames(bus: Bus):
    """loop:// returns what is written: the PC's command comes back as centre-link bytes."""
    frames: list[Envelope] = []
    bus.subscribe_frames(frames.append, "centre")
    bridge = CentreBridge(bus, "loop://").start()
    try:
        pc = PcEndpoint(bus)
        pc.send("LOn")
        run_until(bus, lambda: bridge.port.bytes_in >= 11, 3, "the looped-back bytes")
        bridge.close()  # flushes the framer: a command is noise on the centre link
        run_until(bus, lambda: frames, 2, "the flushed frame")
        assert b"".join(f.raw for f in frames) == encode_command("LOn")
        assert {(f.src, f.origin, f.kind) for f in frames} == {("hil.loop", "serial", "noise")}
    finally:
        bridge.close()


class LineServer:
    """A ser2net stand-in: a TCP port whose client connection can be dropped and re-accepted."""

    def __init__(self) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.sock.getsockname()[1]}"
        self.conns: list[socket.socket] = []
        self.accepted = threading.Semaphore(0)
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            self.accepted.release()

    def close(self) -> None:
        self.sock.close()
        for c in self.conns:
            c.close()


def test_socket_dropped_gives_fault_and_recovery_and_flushes_the_partial_line(bus: Bus):
    server = LineServer()
    events: list[dict] = []
    frames: list[Envelope] = []
    bus.subscribe_json(f"{bus.keys.root}/event/**", lambda k, d: events.append(d))
    bus.subscribe_frames(frames.append, "centre")
    bridge = CentreBridge(bus, server.url, backoff=Backoff(0.02, 0.1)).start()
    try:
        assert server.accepted.acquire(timeout=3)
        partial = PREAMBLE + b"M: "
        server.conns[-1].sendall(partial)
        run_until(bus, lambda: bridge.port.bytes_in == len(partial), 3, "the partial line")
        server.conns[-1].close()  # ser2net drops the connection
        run_until(bus, lambda: any(e["kind"] == FAULT for e in events), 3, "the fault event")
        fault = next(e for e in events if e["kind"] == FAULT)
        assert "socket disconnected" in fault["message"] and fault["flushed"] == partial.hex()
        assert server.accepted.acquire(timeout=3)  # the bridge reconnected by itself
        run_until(bus, lambda: any(e["kind"] == RECOVERED for e in events), 3, "the recovery event")
        line = PREAMBLE + b"M: ACK," + EOL
        server.conns[-1].sendall(line)
        run_until(bus, lambda: any(f.kind == "ack" for f in frames), 3, "the ACK after recovery")
        assert [(f.kind, f.raw) for f in frames] == [("noise", partial), ("ack", line)]
    finally:
        bridge.close()
        server.close()


def test_port_identity_tells_devices_apart(tmp_path):
    """A link that comes back pointing elsewhere is another device (a pty number the kernel
    hands out again cannot be told from the old one: same device number, same inode)."""
    from hil.port import port_identity

    link = tmp_path / "ttyX"
    link.symlink_to("/dev/null")
    first = port_identity(str(link))
    assert first.startswith("/dev/null (device 1:3")
    link.unlink()
    link.symlink_to("/dev/zero")
    assert port_identity(str(link)) != first
    link.unlink()
    assert "No such file" in port_identity(str(link))
    assert port_identity("socket://lab:7000") == "socket://lab:7000"

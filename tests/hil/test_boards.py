"""``hexbench boards``: which board answers on which port, against stand-ins on ptys (two v2
modules, ids 7 and 126, and a thesis-2009 one) and a pty with nothing behind it; what it
makes of collisions and echoes, from frames."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from serial.tools.list_ports_common import ListPortInfo

from bus.codec import FIRMWARE_VERSION, Frame, Kind, Link, encode_ack, encode_command, encode_position, encode_version, noise, parse
from bus.functions import FunctionCode as F
from hexbench import boards
from hexbench.boards import Answer, Port
from hexbench.cli import main
from hexbench.standin import StandIn
from hil.pty import Pty

VERSION = "%d.%d" % FIRMWARE_VERSION

ROOT = Path(__file__).resolve().parents[2]
BOOT_TIMEOUT_S = 40.0


@pytest.fixture(scope="module")
def desk(tmp_path_factory):
    """Three booted stand-ins and an empty pty, by name."""
    d = tmp_path_factory.mktemp("boards")
    started = [StandIn.on_pty(d / "hx7", module_id=7, profile="v2").start(),
               StandIn.on_pty(d / "hx126", module_id=126, profile="v2").start(),
               StandIn.on_pty(d / "hx3", module_id=3, profile="thesis-2009").start()]
    empty = Pty(d / "hx-empty")
    try:
        threads = [threading.Thread(target=s.wait_booted, args=(BOOT_TIMEOUT_S,)) for s in started]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for s in started:
            assert s.booted.is_set(), f"stand-in m{s.module_id} did not boot"
        yield {"v2-7": started[0], "v2-126": started[1], "thesis": started[2], "empty": empty,
               "dir": d}
    finally:
        for s in started:
            s.close()
        empty.close()


def test_boards_names_each_board_on_its_port(desk, monkeypatch, capsys):
    """An adapter list_ports finds (faked: its device is m7's pty, with a USB serial number and a
    by-id link) and three ports given: each row says who answers there."""
    m7, m126, thesis, empty = desk["v2-7"], desk["v2-126"], desk["thesis"], desk["empty"]
    device = os.path.realpath(m7.path)
    info = ListPortInfo(device, skip_link_detection=True)
    info.serial_number, info.description = "HX0007", "FT232R USB UART"
    by_id = desk["dir"] / "by-id"
    by_id.mkdir()
    (by_id / "usb-FTDI_FT232R_USB_UART_HX0007-if00-port0").symlink_to(device)
    monkeypatch.setattr("serial.tools.list_ports.comports", lambda *a, **k: [info])
    monkeypatch.setattr(boards, "BY_ID", by_id)

    code = main(["boards", "--json", "--scan", m126.path, thesis.path, empty.path])
    rows = {r["port"]: r for r in json.loads(capsys.readouterr().out)}
    assert code == 0
    assert list(rows) == [device, m126.path, thesis.path, empty.path]

    r = rows[device]
    assert (r["usb_serial"], r["description"]) == ("HX0007", "FT232R USB UART")
    assert r["by_id"] == str(by_id / "usb-FTDI_FT232R_USB_UART_HX0007-if00-port0")
    assert (r["kind"], r["ids"], r["profile"], r["firmware"], r["localized"], r["role"]) == \
        ("v2", [7], "v2", VERSION, False, "mobile")
    assert r["next"] == f"hexbench run <scenario> --real 7={r['by_id']}"  # the stable name
    assert not r["collisions"]

    r = rows[m126.path]
    assert (r["kind"], r["ids"], r["firmware"], r["localized"]) == ("v2", [126], VERSION, False)
    assert r["what"] == f"module 126: v2, firmware {VERSION}, not localized, mobile"

    r = rows[thesis.path]
    assert (r["kind"], r["ids"], r["profile"], r["firmware"]) == ("thesis-2009", [], "thesis-2009", None)
    assert r["what"].startswith("thesis-2009 (or a module without v2)")
    assert "--profile thesis-2009" in r["next"]

    r = rows[empty.path]
    assert (r["kind"], r["answered"], r["what"]) == ("no answer", False, "no answer")
    assert "power-cycle the module" in r["next"]
    for r in rows.values():  # all at once, each bounded
        assert r["seconds"] < 8, r


def test_boards_table_and_exit_statuses(desk):
    """The table as a person reads it (the command line, ports given only); exit 1 when nobody
    answers, 2 for a URL pyserial does not know."""
    m7, thesis, empty = desk["v2-7"], desk["thesis"], desk["empty"]
    cmd = [sys.executable, "-m", "hexbench", "boards"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(cmd + [m7.path, thesis.path, empty.path], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].split() == ["PORT", "USB", "SERIAL", "ANSWER", "NEXT", "STEP"]
    row = {line.split()[0]: line for line in lines[1:]}
    assert f"module 7: v2, firmware {VERSION}, not localized, mobile" in row[m7.path]
    assert f"hexbench run <scenario> --real 7={m7.path}" in row[m7.path]
    assert "thesis-2009 (or a module without v2)" in row[thesis.path]
    assert "no answer" in row[empty.path]
    # every column starts at the same place in every row
    starts = {line.index("hexbench run") for line in lines[1:] if "hexbench run" in line}
    assert len(starts) == 1 and lines[0].index("NEXT STEP") in starts

    out = subprocess.run(cmd + [str(desk["dir"] / "no-such-port")], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "cannot open: No such file or directory" in out.stdout, out
    out = subprocess.run(cmd + ["nosuch://x"], cwd=ROOT, env=env, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2 and "protocol 'nosuch' not known" in out.stderr, out


def test_boards_asks_only_the_ports_given(tmp_path, monkeypatch, capsys):
    """`hexbench boards PORT` asked every adapter list_ports found as well (a /dev/ttyS0 the owner
    did not name, which may drive something else): only the ports given are opened now; an
    adapter given by its by-id link is still described by what list_ports knows of it."""
    given, other = Pty(tmp_path / "given"), Pty(tmp_path / "not-given")
    try:
        infos = []
        for pty, serial_number in ((given, "HX0001"), (other, "HX0002")):
            info = ListPortInfo(os.path.realpath(pty.path), skip_link_detection=True)
            info.serial_number = serial_number
            infos.append(info)
        monkeypatch.setattr("serial.tools.list_ports.comports", lambda *a, **k: infos)
        monkeypatch.setattr(boards, "SETTLE_S", 0.1)

        assert main(["boards", "--json", "--timeout", "0.2", given.path]) == 1  # nobody answers
        rows = json.loads(capsys.readouterr().out)
        assert [(r["port"], r["usb_serial"]) for r in rows] == [(given.path, "HX0001")]
        assert given.read(64) == encode_command(F.Report)  # asked ...
        assert other.read(64) == b""  # ... and the adapter not given was never written to
    finally:
        given.close()
        other.close()


# -- what the answers mean (frames, no ports) -------------------------------------------------------
def _frames(*raw: bytes) -> list[Frame]:
    return [parse(Link.CENTRE, r) for r in raw]


def _pos(ident: int, **kw) -> bytes:
    return encode_position(ident, 0, 0, 0, **{"localized": False, "mobile": True, "substrate": False,
                                              "role": b"M: ", **kw})


def test_two_modules_on_one_transceiver_are_collisions():
    a = Answer(Port("/dev/ttyUSB0"), report=_frames(_pos(7), _pos(9), encode_ack(F.Report, role=b"M: ")))
    assert a.kind == "v2" and a.collided and a.ids == [7, 9]
    assert a.what() == "modules 7, 9: v2, mobile; 2 POS lines: several modules answer at once (collisions)"
    assert a.next_step().startswith("leave one module in front of this transceiver")

    a = Answer(Port("/dev/ttyUSB0"), report=[noise(Link.CENTRE, b"\n\r\x8a\xfe", "collided")])
    assert (a.kind, a.answered, a.collided) == ("garbled", False, True)
    assert "several modules answering at once, or a wrong baud rate" in a.what()
    assert "--baud" in a.next_step()


def test_one_answer_and_noise_is_flagged():
    a = Answer(Port("p"), report=_frames(_pos(7), encode_ack(F.Report, role=b"M: "))
               + [noise(Link.CENTRE, b"\xfe\xfe", "x")],
               version=_frames(encode_version(role=b"M: "), encode_ack(F.Version, role=b"M: ")))
    assert a.kind == "v2" and a.collided
    assert a.what().endswith("; 2 noise byte(s): several modules answer at once (collisions)")


def test_a_localized_substrate_and_older_v2_firmware():
    ack = encode_ack(F.Report, role=b"S: ")
    a = Answer(Port("p", by_id="/dev/serial/by-id/usb-x"),
               report=_frames(_pos(5, localized=True, mobile=False, substrate=True, role=b"S: "), ack),
               version=_frames(encode_ack(ord("N"), role=b"S: ")))
    assert a.what() == "module 5: v2, firmware without Version (before 2.1), localized at (0, 0) Yref 0, substrate"
    assert a.next_step() == "hexbench run <scenario> --real 5=/dev/serial/by-id/usb-x"


def test_an_adapter_that_echoes_the_pc_is_not_a_collision():
    report = encode_command(F.Report)
    a = Answer(Port("p"))
    a.report = boards._heard(a, [noise(Link.CENTRE, report, "no frame")]
                             + _frames(encode_ack(ord("N"), role=b"M: ")), report)
    assert a.echo and not a.collided and a.kind == "thesis-2009"
    assert [f.kind for f in a.report] == [Kind.ACK]


def test_a_booting_module():
    a = Answer(Port("p"), before=_frames(b"\n\r\n\rM: COMM. BOARD READY\n\r"))
    assert a.kind == "booting" and "wait until it has booted" in a.next_step()

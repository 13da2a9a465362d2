"""``hexbench firmware flash`` through the real avrdude against the STK500 stand-in on a pty,
and the stand-in's chip on its own.

A board that still holds "the 2009 firmware" (a recognisable fake image, the thesis fuses,
an EEPROM without a board record) is backed up byte for byte, then holds the new image, our
fuses and the record naming it; the rest of its EEPROM survives the chip erase (EESAVE is
programmed before the erase). A board whose record names the other board, a machine
without avrdude and a programmer that does not answer each end in one line and exit 2.
"""

from __future__ import annotations

import shlex
import signal
import subprocess
import time
from pathlib import Path
from typing import Iterator

import pytest

from bus.chip import FUSES, ISP_BITCLOCK_US, THESIS_FUSES, BoardKind, Fuses, board_record, read_board_record
from hexbench.cli import main
from hexbench.firmware import flash_image
from hil.avrdude import BACKUP_MEMORIES, STOP_S, Avrdude, run_deadline_s, used
from hil.isp import (EEPROM_SIZE, FLASH_SIZE, MEMORY_SIZES, OK, PROG_PAGE, READ_PAGE, SCK_DURATION, UNIVERSAL,
                     Atmega162, EmptySocket, Stk500Programmer, format_ihex, parse_ihex, read_ihex)
from hil.pty import Pty
from processes import hexbench
from toolchain import needs_avr, needs_tools

#: For tests that run the real avrdude.
needs_avrdude = needs_tools("avrdude")

#: A silent programmer costs avrdude one read timeout (5 s) before hexbench stops it.
SILENT_BOUND_S = 15.0


def board_of_2009() -> Atmega162:
    """A chip as a 2009 board left it: 10 KiB of program, the thesis fuses, an EEPROM with
    data but no board record."""
    chip = Atmega162(THESIS_FUSES)
    program = b"HexBot thesis firmware 2009 " + bytes((i * 7 + 3) & 0xFF for i in range(10 * 1024))
    chip.flash[:len(program)] = program
    chip.eeprom[:] = (b"2009" + bytes(range(256)) * 2)[:EEPROM_SIZE]
    return chip


def snapshot(chip: Atmega162) -> dict[str, bytes]:
    return {name: bytes(data) for name, data in chip.memories.items()}


@pytest.fixture
def programmer(tmp_path: Path) -> Iterator[Stk500Programmer]:
    """An STK500 stand-in with a 2009 board in its socket, behind ``<tmp>/isp``."""
    with Stk500Programmer.on_pty(tmp_path / "isp", board_of_2009()) as p:
        yield p


def flash(board: str, port: str, backups: Path, *extra: str) -> int:
    return main(["firmware", "flash", "--board", board, "--profile", "v2", "--programmer", "stk500v1",
                 "--port", port, "--backup-dir", str(backups), *extra])


def backup_folder(backups: Path) -> Path:
    folders = list(backups.iterdir())
    assert len(folders) == 1, folders
    return folders[0]


# -- through avrdude -------------------------------------------------------------------------------
@needs_avr
@needs_avrdude
@pytest.mark.parametrize("board", ["comm", "control"])
def test_flash_backs_the_board_up_then_writes_fuses_image_and_record(programmer, tmp_path, capsys, board):
    chip = programmer.chip
    before = snapshot(chip)
    started = time.monotonic()
    assert flash(board, programmer.path, tmp_path / "backups") == 0
    took = time.monotonic() - started
    out = capsys.readouterr()
    assert out.err == ""

    folder = backup_folder(tmp_path / "backups")
    for name in BACKUP_MEMORIES:
        assert bytes(read_ihex(folder / f"{name}.hex", MEMORY_SIZES[name])) == before[name], name
    image = flash_image(board, "v2")
    assert chip.flash == parse_ihex(image.read_text(), FLASH_SIZE)
    assert chip.fuses == FUSES
    assert chip.erases == 1
    assert read_board_record(chip.eeprom) == BoardKind[board.upper()]
    assert chip.eeprom[4:] == before["eeprom"][4:]  # EESAVE was programmed before the erase
    assert f"backup: {folder} " in out.out and "board record: none" in out.out
    assert "3 of 3 verified" in out.out and "4 B verified" in out.out
    assert took < 20, f"a flash took {took:.1f} s"


@needs_avr
@needs_avrdude
def test_a_board_whose_record_names_the_other_board_is_refused(programmer, tmp_path, capsys):
    chip = programmer.chip
    chip.eeprom[:4] = board_record(BoardKind.CONTROL)
    before = snapshot(chip)
    assert flash("comm", programmer.path, tmp_path / "backups") == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "control board, not a comm board" in err[0] and "--force-board" in err[0]
    assert snapshot(chip) == before and chip.erases == 0
    assert (backup_folder(tmp_path / "backups") / "eeprom.hex").exists()  # the backup is kept

    assert flash("comm", programmer.path, tmp_path / "forced", "--force-board") == 0
    assert read_board_record(chip.eeprom) == BoardKind.COMM


@needs_avr
@needs_avrdude
def test_the_backup_restores_the_board_with_one_avrdude_line(programmer, tmp_path):
    before = snapshot(programmer.chip)
    assert flash("comm", programmer.path, tmp_path / "backups") == 0
    folder = backup_folder(tmp_path / "backups")
    # docs/firmware.md, "Flashing a board": the restore line
    r = subprocess.run(["avrdude", "-q", "-p", "m162", "-c", "stk500v1", "-P", programmer.path, "-B", "8",
                        *(f"-U{m}:w:{folder}/{m}.hex:i" for m in BACKUP_MEMORIES)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert snapshot(programmer.chip) == before


@needs_avr
@needs_avrdude
def test_a_chip_that_cannot_follow_the_isp_clock_is_one_line_and_exit_2(programmer, tmp_path, capsys):
    programmer.parameters[SCK_DURATION] = 1  # 921.6 kHz: an STK500 left fast (avrdude 7.1 ignores -B)
    assert flash("comm", programmer.path, tmp_path / "backups") == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "does not enter programming mode" in err[0] and "--bitclock" in err[0], err


@needs_avr
@needs_avrdude
def test_a_failed_verification_names_the_backup_and_exits_1(programmer, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(programmer.chip, "write_flash", lambda addr, data: None)  # a worn-out flash
    assert flash("comm", programmer.path, tmp_path / "backups") == 1
    err = capsys.readouterr().err.splitlines()
    folder = backup_folder(tmp_path / "backups")
    assert len(err) == 1 and "reads back other bytes" in err[0] and str(folder) in err[0], err


@needs_avrdude
def test_a_programmer_that_does_not_answer_is_one_line_and_exit_2(tmp_path, capsys):
    line = Pty(tmp_path / "isp")  # nothing behind it
    try:
        started = time.monotonic()
        assert flash("comm", line.path, tmp_path / "backups") == 2
        took = time.monotonic() - started
    finally:
        line.close()
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "does not answer" in err[0] and "nothing was written" in err[0], err
    assert took < SILENT_BOUND_S, f"took {took:.1f} s"
    assert list((tmp_path / "backups").iterdir()) == []  # a failed backup leaves no folder


# -- a programmer that stops answering half-way ------------------------------------------------------
class SilentFrom:
    """A :attr:`Stk500Programmer.silent_from`: the programmer answers ``answered`` commands
    that start with ``head``, and from the next one on nothing at all (it hung)."""

    def __init__(self, head: bytes, answered: int = 0) -> None:
        self.head, self.left = head, answered

    def __call__(self, command: bytes) -> bool:
        if command.startswith(self.head):
            self.left -= 1
        return self.left < 0


#: The bound docs/firmware.md states for the whole command: each run's deadline, the runs of
#: a flash of the comm image in turn, and the SIGTERM grace of the one that is stopped.
def command_bound_s(board: str) -> float:
    image = parse_ihex(flash_image(board, "v2").read_text(), FLASH_SIZE)
    return (run_deadline_s(ISP_BITCLOCK_US, read=sum(MEMORY_SIZES[m] for m in BACKUP_MEMORIES))
            + run_deadline_s(ISP_BITCLOCK_US, fuses=3)
            + run_deadline_s(ISP_BITCLOCK_US, flash=used(image), eeprom=4) + STOP_S)


@needs_avr
@needs_avrdude
@pytest.mark.slow
@pytest.mark.parametrize("silence", [
    SilentFrom(bytes((UNIVERSAL, 0xAC, 0xA8))),  # the high fuse write (0xD9 -> 0xD1)
    SilentFrom(bytes((PROG_PAGE,))),  # after the chip erase, before any page
    SilentFrom(bytes((PROG_PAGE,)), answered=10),  # ten pages written of 86 (issue 50)
], ids=["at-the-fuses", "after-the-chip-erase", "after-ten-pages"])
def test_a_programmer_that_stops_answering_while_writing_ends_in_bounded_time(
        programmer, tmp_path, capsys, silence):
    """avrdude retries a silent programmer byte by byte for minutes: each run's deadline stops
    it, and the command ends with exit 1, the backup folder and the one line that restores it
    (which, run on the replugged programmer, puts the board back as it was)."""
    before = snapshot(programmer.chip)
    programmer.silent_from = silence
    started = time.monotonic()
    assert flash("comm", programmer.path, tmp_path / "backups") == 1
    took = time.monotonic() - started
    assert programmer.silent
    err = capsys.readouterr().err.splitlines()
    folder = backup_folder(tmp_path / "backups")
    assert len(err) == 1, err
    assert "s deadline" in err[0] and "and was stopped: the programmer (-c stk500v1 -P " in err[0], err
    assert f"stopped answering; the board may be half-written: its previous memories are in {folder}" in err[0]
    assert took < command_bound_s("comm"), f"took {took:.1f} s"

    restore = err[0].split("restore them with: ", 1)[1]
    assert restore.startswith("avrdude ") and str(folder) in restore
    chip = programmer.chip
    programmer.close()  # unplugged and plugged back in: a programmer that answers
    with Stk500Programmer.on_pty(tmp_path / "isp", chip):
        r = subprocess.run(shlex.split(restore), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert snapshot(chip) == before


@needs_avrdude
def test_a_programmer_that_stops_answering_while_backing_up_writes_nothing(programmer, tmp_path, capsys):
    before = snapshot(programmer.chip)
    programmer.silent_from = SilentFrom(bytes((READ_PAGE,)), answered=10)
    started = time.monotonic()
    assert flash("comm", programmer.path, tmp_path / "backups") == 2
    took = time.monotonic() - started
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "backup failed, nothing was written" in err[0] and "does not answer" in err[0], err
    assert took < SILENT_BOUND_S, f"took {took:.1f} s"
    assert snapshot(programmer.chip) == before and list((tmp_path / "backups").iterdir()) == []


# -- lock bits -------------------------------------------------------------------------------------
@needs_avr
@needs_avrdude
def test_the_backup_keeps_the_lock_bits_and_the_restore_puts_them_back(programmer, tmp_path, capsys):
    """A write-protected 2009 board (lock mode 2: LB1 programmed, still readable): the backup
    holds its lock byte; the chip takes no fuse before an erase, so it is erased first and its
    EEPROM written back from the backup; the restore line locks it again, after the flash."""
    chip = programmer.chip
    chip.memories["lock"][0] = 0xFE
    before = snapshot(chip)
    assert flash("comm", programmer.path, tmp_path / "backups") == 0
    out = capsys.readouterr().out
    folder = backup_folder(tmp_path / "backups")
    assert read_ihex(folder / "lock.hex", 1) == b"\xfe" and "lock 0xFE" in out
    assert chip.lock == 0xFF and read_board_record(chip.eeprom) == BoardKind.COMM
    assert chip.fuses == FUSES and chip.flash == parse_ihex(flash_image("comm", "v2").read_text(), FLASH_SIZE)
    assert chip.eeprom[4:] == before["eeprom"][4:]  # erased with EESAVE off, written back
    assert "the rest as backed up, 512 B verified" in out

    restore = Avrdude("stk500v1", programmer.path).restore_command(folder)
    r = subprocess.run(shlex.split(restore), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert snapshot(chip) == before


@needs_avrdude
def test_a_chip_locked_against_reading_is_no_backup(programmer, tmp_path, capsys):
    """Lock mode 3 (LB1 and LB2 programmed): flash and EEPROM read back as a pattern. That is
    refused in one line, exit 2, no backup folder, nothing written."""
    chip = programmer.chip
    chip.memories["lock"][0] = 0xFC
    before = snapshot(chip)
    assert flash("comm", programmer.path, tmp_path / "backups") == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert "the chip is locked (lock byte 0xFC: LB2 programmed)" in err[0] and "not a backup" in err[0]
    assert "nothing was written" in err[0] and " -e" in err[0]
    assert snapshot(chip) == before and chip.erases == 0
    assert list((tmp_path / "backups").iterdir()) == []


@needs_avrdude
@pytest.mark.parametrize("level", [0x00, 0xFF])
def test_a_chip_that_does_not_answer_is_not_called_a_wrong_chip(tmp_path, capsys, level):
    """MISO held low or high reads as signature 0x000000 / 0xffffff: no chip answers (power,
    cable, bit clock), which is not another part; avrdude's "(retrying)" stays out."""
    with Stk500Programmer.on_pty(tmp_path / "isp", EmptySocket(level)) as p:
        assert flash("comm", p.path, tmp_path / "backups") == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert f"no chip answers the programmer (-c stk500v1; signature 0x{level:02x}{level:02x}{level:02x})" in err[0]
    assert "power" in err[0] and "--bitclock" in err[0] and "nothing was written" in err[0]
    assert "retrying" not in err[0] and "not an ATmega162" not in err[0]
    assert list((tmp_path / "backups").iterdir()) == []


@needs_avrdude
def test_another_part_is_named_by_its_signature(programmer, tmp_path, capsys):
    programmer.chip.signature = bytes((0x1E, 0x94, 0x03))  # an ATmega16 in the socket
    assert flash("comm", programmer.path, tmp_path / "backups") == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "the chip is not an ATmega162: its signature is 0x1e9403 (m16), not 0x1e9404" in err[0], err
    assert programmer.chip.erases == 0


def test_no_avrdude_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    assert flash("comm", "/dev/null", tmp_path / "backups") == 2
    assert capsys.readouterr().err == ("hexbench firmware: error: avrdude not found: "
                                       "apt-get install avrdude\n")
    assert not (tmp_path / "backups").exists()


@needs_avrdude
def test_the_standin_command_answers_avrdude_and_saves_its_chip(tmp_path):
    board_of_2009().save(tmp_path / "2009")
    proc = hexbench("programmer-standin", "--pty", "--link", str(tmp_path / "isp"),
                    "--load", str(tmp_path / "2009"), "--save", str(tmp_path / "after"))
    try:
        assert "avrdude -c stk500v1 -p m162" in proc.stdout.readline()
        r = subprocess.run(["avrdude", "-q", "-p", "m162", "-c", "stk500v1", "-P", str(tmp_path / "isp"),
                            "-U", f"hfuse:w:0x{FUSES.high:02X}:m"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
    finally:
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=10)[0]
    assert proc.returncode == 0, rest
    saved = Atmega162().load(tmp_path / "after")
    assert saved.fuses.high == FUSES.high and saved.flash == board_of_2009().flash


# -- the chip and the protocol on their own ----------------------------------------------------------
def standin(chip: Atmega162) -> Stk500Programmer:
    """A stand-in whose answers the test reads from :meth:`Stk500Programmer.answer`."""
    return Stk500Programmer(Pty(), chip)


@pytest.mark.parametrize("hfuse,kept", [(FUSES.high, True), (THESIS_FUSES.high, False)])
def test_a_chip_erase_keeps_the_eeprom_only_with_eesave_programmed(hfuse, kept):
    chip = board_of_2009()
    chip.fuses = Fuses(low=FUSES.low, high=hfuse, extended=FUSES.extended)
    eeprom = bytes(chip.eeprom)
    chip.spi(bytes((0xAC, 0x80, 0, 0)))
    assert chip.flash == b"\xff" * FLASH_SIZE and chip.lock == 0xFF
    assert chip.eeprom == (eeprom if kept else b"\xff" * EEPROM_SIZE)


def test_a_flash_page_write_only_clears_bits_and_serial_programming_keeps_spien():
    p = standin(Atmega162())
    try:
        p.chip.flash[:2] = b"\x0f\xff"
        assert p.answer(bytes((0x55, 0, 0, 0x20))) == bytes((0x14, OK))  # word address 0
        assert p.answer(bytes((0x64, 0, 2, ord("F"), 0xF0, 0x3C, 0x20))) == bytes((0x14, OK))
        assert p.chip.flash[:2] == b"\x00\x3c"  # 0x0f & 0xf0, 0xff & 0x3c: no erase, no ones
        p.chip.spi(bytes((0xAC, 0xA8, 0, 0xFF)))  # hfuse 0xFF would turn SPIEN off
        assert p.chip.fuses.high == 0xDF
    finally:
        p.close()


def test_a_1_mhz_chip_does_not_enter_programming_mode_at_a_fast_sck():
    p = standin(Atmega162())  # the factory low fuse: 1 MHz
    try:
        assert p.answer(bytes((0x40, 0x89, 1, 0x20))) == bytes((0x14, OK))  # SCK 921.6 kHz
        assert p.answer(bytes((0x50, 0x20))) == bytes((0x14, 0x11))  # Resp_STK_FAILED
        assert p.answer(bytes((0x40, 0x89, 7, 0x20))) == bytes((0x14, OK))  # 131.7 kHz (-B 8)
        assert p.answer(bytes((0x50, 0x20))) == bytes((0x14, OK)) and p.progmode
    finally:
        p.close()


def test_a_chip_saved_to_a_folder_loads_back_the_same(tmp_path):
    chip = board_of_2009()
    chip.save(tmp_path / "chip")
    assert snapshot(Atmega162().load(tmp_path / "chip")) == snapshot(chip)
    assert parse_ihex(format_ihex(b"\x01\x02", start=0x1FFFF), 0x20001)[0x1FFFF:] == b"\x01\x02"

"""avrdude, driven for one ATmega162 behind one ISP programmer.

Each method is one avrdude run (a subprocess, no shell) with ``-p m162 -c PROGRAMMER
[-P PORT] -B BITCLOCK``; avrdude verifies what it writes. A failed run raises
:class:`AvrdudeError` with one line that says what went wrong in our words (the
programmer does not answer, the chip does not enter programming mode, a verification
failed), not avrdude's ten.

A programmer that stays silent for avrdude's read timeout (5 s) is not there: while
reading (:meth:`Avrdude.read`, which writes nothing) avrdude is stopped then instead of
retrying ten times (50 s with ``-c stk500v1``). Every run also has a deadline sized to the
bytes it moves at the bit clock (:func:`run_deadline_s`): a programmer that stops answering
half-way through a write, which avrdude retries byte by byte for minutes, ends the run then.
"""

from __future__ import annotations

import math
import os
import re
import shlex
import shutil
import subprocess
import threading
from pathlib import Path

from bus.chip import (AVRDUDE_PART, EEPROM_SIZE, FLASH_PAGE, FLASH_SIZE, ISP_BITCLOCK_US,
                      ISP_INSTRUCTION_BITS, SIGNATURE, T_WD_EEPROM_S, T_WD_ERASE_S, T_WD_FLASH_S,
                      T_WD_FUSE_S, Fuses)
from bus.errors import HexbenchError

from .isp import MEMORY_SIZES, read_ihex

#: What a backup holds: every memory a flash changes, the lock byte (a chip erase clears it)
#: last, so that a restore writes it after the flash whose erase would clear it again.
BACKUP_MEMORIES = ("flash", "eeprom", "lfuse", "hfuse", "efuse", "lock")
#: A run's deadline: what its bytes take at the bit clock, DEADLINE_MARGIN times over, plus
#: RUN_OVERHEAD_S (avrdude's start, sync and signature, a USB programmer's setup). It bounds a
#: programmer that stopped answering, not a slow one: both are generous.
RUN_OVERHEAD_S = 10.0
DEADLINE_MARGIN = 3.0
#: The line to a serial programmer (avrdude's default for ``-c stk500v1``); USB ones are faster.
PROGRAMMER_BAUD = 115_200
#: After SIGTERM, how long avrdude may take to go before it is killed.
STOP_S = 5.0
_SILENT = "programmer is not responding"
#: What avrdude says it is doing ("writing 10936 bytes flash ...", "erasing chip").
_DOING = re.compile(r"^avrdude: ((?:reading|writing|verifying|erasing) [^.]*)")
_VERIFIED = re.compile(r"(\d+) bytes? of (\w+) verified")
#: "device signature = 0x1e9403 (probably m16)", "... = 0x000000 (retrying)"
_SIGNATURE = re.compile(r"device signature = 0x([0-9a-fA-F]{6})(?: \(probably ([^)]+)\))?")


class AvrdudeError(HexbenchError):
    """avrdude is missing or a run failed; the message is one line."""


class Avrdude:
    """avrdude with ``programmer`` (its ``-c``) on ``port`` (its ``-P``; None: avrdude's
    default for that programmer, ``usb`` for an AVRISP mkII)."""

    def __init__(self, programmer: str, port: str | None = None, *,
                 bitclock_us: float = ISP_BITCLOCK_US) -> None:
        exe = shutil.which("avrdude")
        if exe is None:
            raise AvrdudeError("avrdude not found: apt-get install avrdude")
        self.exe = exe
        self.programmer = programmer
        self.port = port
        self.bitclock_us = bitclock_us

    def command(self, *args: str) -> list[str]:
        """The avrdude command line with ``args`` (its ``-U`` operations)."""
        port = ["-P", self.port] if self.port else []
        return [self.exe, "-q", "-p", AVRDUDE_PART, "-c", self.programmer, *port,
                "-B", f"{self.bitclock_us:g}", *args]

    def command_line(self, *args: str) -> str:
        """:meth:`command` as a person types it."""
        return shlex.join(["avrdude", *self.command(*args)[1:]])

    def restore_command(self, folder: str | os.PathLike[str]) -> str:
        """The one avrdude line that writes a backup folder back (flash first: its chip erase
        comes before the EEPROM, the fuses and the lock byte)."""
        return self.command_line(*(f"-U{m}:w:{Path(folder) / f'{m}.hex'}:i" for m in BACKUP_MEMORIES))

    @property
    def _on(self) -> str:
        return f"-c {self.programmer}" + (f" -P {self.port}" if self.port else "")

    def run(self, *args: str, deadline_s: float, stop_when_silent: bool = False) -> str:
        """Run avrdude with ``args``; its messages, or :class:`AvrdudeError` (also when it has
        not finished after ``deadline_s``: it is stopped then)."""
        try:
            proc = subprocess.Popen(self.command(*args), stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                    errors="replace")
        except OSError as exc:
            raise AvrdudeError(f"cannot run {self.exe}: {exc.strerror or exc}") from None
        assert proc.stderr is not None
        lines: list[str] = []

        def take_messages() -> None:
            assert proc.stderr is not None
            for line in proc.stderr:
                lines.append(line)
                if stop_when_silent and _SILENT in line:
                    proc.terminate()

        reader = threading.Thread(target=take_messages, name="avrdude-messages", daemon=True)
        reader.start()
        try:
            code = proc.wait(timeout=deadline_s)
        except subprocess.TimeoutExpired:
            _stop(proc)
            reader.join(timeout=STOP_S)  # the messages up to the stop
            raise AvrdudeError(self._overdue(lines, deadline_s)) from None
        finally:
            reader.join(timeout=STOP_S)  # the pipe ends with the process
            proc.stderr.close()
        if code != 0:
            raise AvrdudeError(self._reason(lines))
        return "".join(lines)

    def _overdue(self, lines: list[str], deadline_s: float) -> str:
        """One line for a run stopped at its deadline: what avrdude was doing, and why."""
        doing = [m.group(1).strip() for m in map(_DOING.match, lines) if m]
        why = (f"the programmer ({self._on}) stopped answering" if any(_SILENT in ln for ln in lines)
               else f"the programmer ({self._on}) is too slow or hung")
        return (f"avrdude had not finished after its {deadline_s:.0f} s deadline"
                + (f" (at: {doing[-1]})" if doing else "") + f" and was stopped: {why}")

    def _reason(self, lines: list[str]) -> str:
        """One line for avrdude's failure."""
        on = self._on
        text = "".join(lines)
        if _SILENT in text or "not in sync" in text:
            return (f"the programmer ({on}) does not answer: is it plugged in, on that port, "
                    f"and a {self.programmer}?")
        if "initialization failed" in text:
            return (f"the programmer ({on}) answers but the chip does not enter programming mode: "
                    "check the ISP cable, the board's power and the ISP clock (--bitclock)")
        memory = ""
        for line in lines:
            said = line.split(":", 1)[-1].strip()
            if "cannot open port" in line:
                return f"{said} (avrdude {on})"
            if "expected signature" in line:
                return self._signature_reason(text)
            if line.startswith("avrdude: verifying "):
                memory = said.split()[1]
            if "!= input" in line:
                return f"avrdude wrote the {memory} but reads back other bytes: {line.strip()}"
        errors = [ln.strip() for ln in lines if "error" in ln] or [ln.strip() for ln in lines if ln.strip()]
        return f"avrdude failed ({on}): {(errors or ['no message'])[0]}"

    def _signature_reason(self, text: str) -> str:
        """A signature of all zeros or all ones is MISO held at one level: no chip answers."""
        found = _SIGNATURE.findall(text)
        if not found:
            return "the chip's signature is unreadable"
        signature, part = found[-1]  # avrdude's last try, without its "(retrying)"
        if signature.lower() in ("000000", "ffffff"):
            return (f"no chip answers the programmer (-c {self.programmer}; signature 0x{signature}): "
                    "check the board's power, the ISP cable and the bit clock (--bitclock)")
        return (f"the chip is not an ATmega162: its signature is 0x{signature}"
                + (f" ({part})" if part and not part.startswith(".") else "")
                + f", not 0x{SIGNATURE.hex()}")

    # -- the steps ----------------------------------------------------------------------------------
    def read(self, folder: str | os.PathLike[str],
             memories: tuple[str, ...] = BACKUP_MEMORIES) -> dict[str, bytes]:
        """Read ``memories`` into ``folder/<memory>.hex`` (Intel hex) and return their bytes.

        The folder must exist. Every file is read back and checked: a file missing or
        unreadable is an :class:`AvrdudeError`, as is a failed run."""
        folder = Path(folder)
        deadline = run_deadline_s(self.bitclock_us, read=sum(MEMORY_SIZES[m] for m in memories))
        self.run(*(f"-U{m}:r:{folder / f'{m}.hex'}:i" for m in memories), deadline_s=deadline,
                 stop_when_silent=True)
        out = {}
        for m in memories:
            try:
                out[m] = bytes(read_ihex(folder / f"{m}.hex", MEMORY_SIZES[m]))
            except (OSError, ValueError) as exc:
                raise AvrdudeError(f"avrdude's {m} read is unusable: {exc}") from None
        return out

    def erase(self) -> None:
        """A chip erase: flash and lock bits to 0xFF, the EEPROM too unless EESAVE is programmed."""
        self.run("-e", deadline_s=run_deadline_s(self.bitclock_us, erase=True))

    def write_fuses(self, fuses: Fuses) -> dict[str, int]:
        """Write the three fuse bytes; the bytes avrdude verified of each."""
        return _verified(self.run(*fuses.avrdude_args(), deadline_s=run_deadline_s(self.bitclock_us, fuses=3)))

    def write(self, *, flash: str | os.PathLike[str], eeprom: str | os.PathLike[str]) -> dict[str, int]:
        """Write Intel-hex files; the bytes avrdude verified of each memory.

        Writing flash erases the chip first (avrdude's auto-erase). EEPROM bytes the file
        does not name are left as they are, by avrdude, and through that erase, by the chip,
        only if EESAVE is programmed."""
        try:
            sizes = {"flash": used(read_ihex(flash, FLASH_SIZE)), "eeprom": used(read_ihex(eeprom, EEPROM_SIZE))}
        except (OSError, ValueError) as exc:
            raise AvrdudeError(f"cannot read the image: {exc}") from None
        return _verified(self.run(f"-Uflash:w:{flash}:i", f"-Ueeprom:w:{eeprom}:i",
                                  deadline_s=run_deadline_s(self.bitclock_us, **sizes)))


def run_deadline_s(bitclock_us: float, *, read: int = 0, flash: int = 0, eeprom: int = 0,
                   fuses: int = 0, erase: bool = False) -> float:
    """The deadline of one avrdude run that reads ``read`` bytes and writes ``flash``,
    ``eeprom`` and ``fuses`` bytes (each written byte is read back: avrdude verifies). A byte
    costs one serial-programming instruction at the bit clock and 10 bits on the programmer's
    line; writes add the chip's waits (a page of flash, a byte of EEPROM, a fuse, the erase
    that writing flash begins with)."""
    per_byte = ISP_INSTRUCTION_BITS * bitclock_us * 1e-6 + 10 / PROGRAMMER_BAUD
    waits = (math.ceil(flash / FLASH_PAGE) * T_WD_FLASH_S + (T_WD_ERASE_S if flash or erase else 0.0)
             + eeprom * T_WD_EEPROM_S + fuses * T_WD_FUSE_S)
    work = (read + 2 * (flash + eeprom + fuses)) * per_byte + waits
    return RUN_OVERHEAD_S + DEADLINE_MARGIN * work


def _stop(proc: subprocess.Popen) -> None:
    """SIGTERM, then SIGKILL if avrdude has not gone after STOP_S."""
    proc.terminate()
    try:
        proc.wait(timeout=STOP_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _verified(said: str) -> dict[str, int]:
    """Memory -> bytes verified, from avrdude's "9876 bytes of flash verified" lines."""
    return {memory: int(n) for n, memory in _VERIFIED.findall(said)}


def used(data: bytes) -> int:
    """Bytes up to the last one that is not erased (0xFF)."""
    return len(data.rstrip(b"\xff"))


__all__ = ["Avrdude", "AvrdudeError", "BACKUP_MEMORIES", "run_deadline_s", "used"]

"""avrdude, driven for one ATmega162 behind one ISP programmer.

Each method is one avrdude run (a subprocess, no shell) with ``-p m162 -c PROGRAMMER
[-P PORT] -B BITCLOCK``; avrdude verifies what it writes. A failed run raises
:class:`AvrdudeError` with one line that says what went wrong in our words (the
programmer does not answer, the chip does not enter programming mode, a verification
failed), not avrdude's ten.

A programmer that stays silent for avrdude's read timeout (5 s) is not there: while
reading (:meth:`Avrdude.read`, which writes nothing) avrdude is stopped then instead of
retrying ten times (50 s with ``-c stk500v1``).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

from bus.chip import AVRDUDE_PART, ISP_BITCLOCK_US, SIGNATURE, Fuses
from bus.errors import HexbenchError

from .isp import MEMORY_SIZES, read_ihex

#: What a backup holds: every memory a flash changes (not the lock byte, which it never writes).
BACKUP_MEMORIES = ("flash", "eeprom", "lfuse", "hfuse", "efuse")
_SILENT = "programmer is not responding"
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

    def run(self, *args: str, stop_when_silent: bool = False) -> str:
        """Run avrdude with ``args``; its messages, or :class:`AvrdudeError`."""
        try:
            proc = subprocess.Popen(self.command(*args), stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                    errors="replace")
        except OSError as exc:
            raise AvrdudeError(f"cannot run {self.exe}: {exc.strerror or exc}") from None
        assert proc.stderr is not None
        lines = []
        with proc.stderr:
            for line in proc.stderr:
                lines.append(line)
                if stop_when_silent and _SILENT in line:
                    proc.terminate()
                    break
        if proc.wait() != 0:
            raise AvrdudeError(self._reason(lines))
        return "".join(lines)

    def _reason(self, lines: list[str]) -> str:
        """One line for avrdude's failure."""
        on = f"-c {self.programmer}" + (f" -P {self.port}" if self.port else "")
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
        self.run(*(f"-U{m}:r:{folder / f'{m}.hex'}:i" for m in memories), stop_when_silent=True)
        out = {}
        for m in memories:
            try:
                out[m] = bytes(read_ihex(folder / f"{m}.hex", MEMORY_SIZES[m]))
            except (OSError, ValueError) as exc:
                raise AvrdudeError(f"avrdude's {m} read is unusable: {exc}") from None
        return out

    def write_fuses(self, fuses: Fuses) -> dict[str, int]:
        """Write the three fuse bytes; the bytes avrdude verified of each."""
        return _verified(self.run(*fuses.avrdude_args()))

    def write(self, *, flash: str | os.PathLike[str], eeprom: str | os.PathLike[str]) -> dict[str, int]:
        """Write Intel-hex files; the bytes avrdude verified of each memory.

        Writing flash erases the chip first (avrdude's auto-erase). EEPROM bytes the file
        does not name are left as they are, by avrdude, and through that erase, by the chip,
        only if EESAVE is programmed."""
        return _verified(self.run(f"-Uflash:w:{flash}:i", f"-Ueeprom:w:{eeprom}:i"))


def _verified(said: str) -> dict[str, int]:
    """Memory -> bytes verified, from avrdude's "9876 bytes of flash verified" lines."""
    return {memory: int(n) for n, memory in _VERIFIED.findall(said)}


def used(data: bytes) -> int:
    """Bytes up to the last one that is not erased (0xFF)."""
    return len(data.rstrip(b"\xff"))


__all__ = ["Avrdude", "AvrdudeError", "BACKUP_MEMORIES", "used"]

"""A programmer stand-in: an STK500 (firmware 1.x) with an ATmega162 in its ISP socket.

avrdude speaks the STK500 version 1 protocol (``-c stk500v1``) over a serial line: every
command is a command byte, its arguments and ``Sync_CRC_EOP`` (0x20); every answer is
``Resp_STK_INSYNC`` (0x14), any data, and ``Resp_STK_OK`` (0x10) or an error byte. Pages of
flash and EEPROM go as ``Cmnd_STK_PROG_PAGE``/``Cmnd_STK_READ_PAGE`` after
``Cmnd_STK_LOAD_ADDRESS`` (a word address for flash, a byte address for EEPROM); the
signature, the fuses, the lock byte and the chip erase go as ``Cmnd_STK_UNIVERSAL``: four
bytes passed through to the chip's own serial programming instructions (ATmega162
datasheet, "Serial Programming Instruction Set"), whose fourth answer byte comes back.

:class:`Atmega162` is the chip as those instructions see it: flash that a page write can
only clear bits of (a chip erase sets them again), EEPROM written byte by byte, fuses, the
lock byte. A chip erase keeps the EEPROM only while EESAVE (bit 3 of the high fuse) is
programmed, and serial programming cannot change SPIEN, as on the part. Lock bits work as on
the part: LB1 programmed stops every write but a chip erase, LB2 as well makes flash and
EEPROM read back as a pattern (the datasheet does not say which; here, the address's low byte). The chip runs at
the clock its low fuse selects (internal RC, CKDIV8), and, like the part, does not enter
programming mode when the programmer's SCK is faster than a quarter of that clock: without
avrdude's ``-B`` a 1 MHz chip does not answer.

:class:`Stk500Programmer` answers avrdude from a chip on a :class:`hil.pty.Pty` (or any
object with pyserial's ``read``/``write``). A chip's memories load from and save to a
folder of Intel-hex files, one per avrdude memory (``flash.hex``, ``eeprom.hex``,
``lfuse.hex``, ...): the layout of the backups ``hexbench firmware flash`` takes.
Run it as ``hexbench programmer-standin --pty``.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Callable, Protocol

from bus.chip import (EEPROM_SIZE, FLASH_PAGE, FLASH_SIZE, ISP_BITCLOCK_US, SIGNATURE, Fuses, reads_disabled,
                      writes_disabled)

# -- Intel hex --------------------------------------------------------------------------------------


def parse_ihex(text: str, size: int) -> bytearray:
    """The ``size`` bytes an Intel-hex text describes; bytes it does not name are 0xFF
    (erased), as avrdude reads a file with holes."""
    out = bytearray(b"\xff" * size)
    base = 0
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        try:
            if not line.startswith(":"):
                raise ValueError("no ':'")
            rec = bytes.fromhex(line[1:])
            count, addr, kind, data = rec[0], int.from_bytes(rec[1:3], "big"), rec[3], rec[4:-1]
            if len(data) != count or sum(rec) & 0xFF:
                raise ValueError("bad length or checksum")
        except (ValueError, IndexError) as exc:
            raise ValueError(f"line {n}: not an Intel-hex record ({exc})") from None
        if kind == 0:
            start = base + addr
            if start + count > size:
                raise ValueError(f"line {n}: address 0x{start:X}+{count} is beyond {size} bytes")
            out[start:start + count] = data
        elif kind == 1:
            break
        elif kind == 2:
            base = int.from_bytes(data, "big") << 4
        elif kind == 4:
            base = int.from_bytes(data, "big") << 16
    return out


def _record(addr: int, kind: int, data: bytes) -> str:
    rec = bytes((len(data), addr >> 8 & 0xFF, addr & 0xFF, kind)) + data
    return f":{rec.hex().upper()}{-sum(rec) & 0xFF:02X}"


def format_ihex(data: bytes, *, start: int = 0, skip_blank: bool = False) -> str:
    """Intel hex of ``data`` placed at ``start``, 16 bytes a record; ``skip_blank`` leaves
    out records that are all 0xFF (an erased flash stays a short file)."""
    lines, upper = [], 0
    for off in range(0, len(data), 16):
        chunk, addr = bytes(data[off:off + 16]), start + off
        if skip_blank and chunk == b"\xff" * len(chunk):
            continue
        if addr >> 16 != upper:
            upper = addr >> 16
            lines.append(_record(0, 4, upper.to_bytes(2, "big")))
        lines.append(_record(addr & 0xFFFF, 0, chunk))
    return "\n".join(lines + [":00000001FF"]) + "\n"


def read_ihex(path: str | os.PathLike[str], size: int) -> bytearray:
    """:func:`parse_ihex` of a file; a bad file raises ValueError naming it."""
    try:
        return parse_ihex(Path(path).read_text(encoding="ascii"), size)
    except ValueError as exc:  # UnicodeDecodeError too
        raise ValueError(f"{path}: {exc}") from None


def fuses_of(memories: dict[str, bytes] | dict[str, bytearray]) -> Fuses:
    """The fuses among avrdude memories (a chip's, or a backup's)."""
    return Fuses(low=memories["lfuse"][0], high=memories["hfuse"][0], extended=memories["efuse"][0])


def fuses_text(fuses: Fuses) -> str:
    """``low 0x62 high 0xD1 extended 0xFF``."""
    return f"low 0x{fuses.low:02X} high 0x{fuses.high:02X} extended 0x{fuses.extended:02X}"


# -- the chip ---------------------------------------------------------------------------------------
#: avrdude's memory names and sizes; a chip image folder holds ``<name>.hex`` for each.
MEMORY_SIZES = {"flash": FLASH_SIZE, "eeprom": EEPROM_SIZE, "lfuse": 1, "hfuse": 1, "efuse": 1,
                "lock": 1}
#: Factory fuses of the ATmega162 (datasheet): 1 MHz internal RC, JTAG on, EESAVE off.
FACTORY_FUSES = Fuses(low=0x62, high=0x99, extended=0xFF)
EESAVE = 0x08  # high fuse: programmed (0) keeps the EEPROM through a chip erase
SPIEN = 0x20  # high fuse: serial programming cannot change it
CKDIV8 = 0x80  # low fuse: programmed (0) divides the clock by 8
RC_HZ = 8_000_000  # the internal RC oscillator
#: Bits that read 1 whatever is written: the extended fuse's unused ones, the lock byte's 7..6.
_UNUSED = {"efuse": 0xE1, "lock": 0xC0}
_WORDS_PER_PAGE = FLASH_PAGE // 2
_EEPROM_PAGE = 4


class Atmega162:
    """An ATmega162's memories, driven by its serial programming instructions (:meth:`spi`)."""

    def __init__(self, fuses: Fuses = FACTORY_FUSES) -> None:
        self.memories = {name: bytearray(b"\xff" * size) for name, size in MEMORY_SIZES.items()}
        self.fuses = fuses
        self.calibration = 0xA5  # the RC oscillator's factory calibration byte
        self.signature = SIGNATURE  # another part in the socket has its own
        self.erases = 0
        self._flash_buffer: dict[int, int] = {}  # the page buffer: byte offset in page -> byte
        self._eeprom_buffer: dict[int, int] = {}

    # -- views --------------------------------------------------------------------------------------
    @property
    def flash(self) -> bytearray:
        return self.memories["flash"]

    @property
    def eeprom(self) -> bytearray:
        return self.memories["eeprom"]

    @property
    def fuses(self) -> Fuses:
        return fuses_of(self.memories)

    @fuses.setter
    def fuses(self, fuses: Fuses) -> None:
        for name, value in (("lfuse", fuses.low), ("hfuse", fuses.high), ("efuse", fuses.extended)):
            self.memories[name][0] = value | _UNUSED.get(name, 0)

    @property
    def lock(self) -> int:
        return self.memories["lock"][0]

    @property
    def programming_disabled(self) -> bool:
        """Lock mode 2 or 3: only a chip erase changes the chip."""
        return writes_disabled(self.lock)

    def read(self, memory: str, addr: int) -> int:
        """A byte of flash or EEPROM as a programmer reads it: a pattern on a chip locked
        against verification (lock mode 3)."""
        data = self.memories[memory]
        return addr & 0xFF if reads_disabled(self.lock) else data[addr % len(data)]

    @property
    def cpu_hz(self) -> int:
        """The clock the low fuse gives (internal RC; CKDIV8 programmed divides it by 8)."""
        return RC_HZ // 8 if not self.memories["lfuse"][0] & CKDIV8 else RC_HZ

    # -- files --------------------------------------------------------------------------------------
    def load(self, folder: str | os.PathLike[str]) -> "Atmega162":
        """Take each ``<memory>.hex`` the folder holds (a backup, or a saved chip)."""
        for name, size in MEMORY_SIZES.items():
            path = Path(folder) / f"{name}.hex"
            if path.exists():
                self.memories[name][:] = read_ihex(path, size)
        return self

    def save(self, folder: str | os.PathLike[str]) -> None:
        """Write every memory as ``<folder>/<memory>.hex``."""
        Path(folder).mkdir(parents=True, exist_ok=True)
        for name, data in self.memories.items():
            (Path(folder) / f"{name}.hex").write_text(format_ihex(data, skip_blank=len(data) > 1),
                                                     encoding="ascii")

    # -- programming --------------------------------------------------------------------------------
    def chip_erase(self) -> None:
        """Flash and lock bits to 0xFF; the EEPROM too unless EESAVE is programmed."""
        self.flash[:] = b"\xff" * FLASH_SIZE
        self.memories["lock"][0] = 0xFF
        if self.memories["hfuse"][0] & EESAVE:
            self.eeprom[:] = b"\xff" * EEPROM_SIZE
        self.erases += 1

    def write_flash(self, addr: int, data: bytes) -> None:
        """Program bytes from ``addr``: a write clears bits, only an erase sets them."""
        if self.programming_disabled:
            return
        flash = self.flash
        for i, b in enumerate(data):
            flash[(addr + i) % FLASH_SIZE] &= b

    def write_eeprom(self, addr: int, data: bytes) -> None:
        """EEPROM writes erase the byte first: the byte becomes ``data``."""
        if self.programming_disabled:
            return
        for i, b in enumerate(data):
            self.eeprom[(addr + i) % EEPROM_SIZE] = b

    def _write_fuse(self, name: str, value: int) -> None:
        if self.programming_disabled:
            return
        if name == "hfuse":
            value = value & ~SPIEN | self.memories["hfuse"][0] & SPIEN
        self.memories[name][0] = value | _UNUSED.get(name, 0)

    def spi(self, instr: bytes) -> int:
        """One 4-byte serial programming instruction; the byte the chip shifts out last."""
        op, b1, b2, b3 = instr
        word = (b1 << 8 | b2) & 0x1FFF
        if op in (0x20, 0x28):  # read program memory, low/high byte of a word
            return self.read("flash", word * 2 + (op == 0x28))
        if op in (0x40, 0x48):  # load program memory page, low/high byte
            self._flash_buffer[(b2 % _WORDS_PER_PAGE) * 2 + (op == 0x48)] = b3
        elif op == 0x4C:  # write program memory page
            page = word - word % _WORDS_PER_PAGE
            for off, b in self._flash_buffer.items():
                self.write_flash(page * 2 + off, bytes((b,)))
            self._flash_buffer.clear()
        elif op == 0xA0:  # read EEPROM
            return self.read("eeprom", b1 << 8 | b2)
        elif op == 0xC0:  # write EEPROM
            self.write_eeprom(b1 << 8 | b2, bytes((b3,)))
        elif op == 0xC1:  # load EEPROM page
            self._eeprom_buffer[b2 % _EEPROM_PAGE] = b3
        elif op == 0xC2:  # write EEPROM page
            page = (b1 << 8 | b2) & ~(_EEPROM_PAGE - 1)
            for off, b in self._eeprom_buffer.items():
                self.write_eeprom(page + off, bytes((b,)))
            self._eeprom_buffer.clear()
        elif op == 0x30:  # read signature byte
            return self.signature[b2 & 3] if b2 & 3 < len(self.signature) else 0x00
        elif op == 0x38:  # read calibration byte
            return self.calibration
        elif (op, b1) in _READS:
            return self.memories[_READS[op, b1]][0]
        elif op == 0xAC:
            if b1 & 0xE0 == 0x80:  # chip erase
                self.chip_erase()
            elif b1 & 0xE0 == 0xE0:  # write lock bits: they can only be programmed
                self.memories["lock"][0] &= b3 | 0xC0
            elif b1 in _FUSE_WRITES:
                self._write_fuse(_FUSE_WRITES[b1], b3)
            elif b1 == 0x53:  # programming enable: echoed in the third byte
                return b2
        return 0x00  # also "ready" for the 0xF0 poll


class EmptySocket(Atmega162):
    """No chip answers the programmer (an empty socket, an unpowered board, a loose ISP cable,
    or SCK too fast for the chip): MISO stays at one ``level``, so every instruction's answer
    byte, the signature's too, is 0x00 (MISO pulled low) or 0xFF (floating high)."""

    def __init__(self, level: int) -> None:
        super().__init__()
        self.level = level

    def spi(self, instr: bytes) -> int:
        return self.level


_READS = {(0x50, 0x00): "lfuse", (0x58, 0x08): "hfuse", (0x50, 0x08): "efuse", (0x58, 0x00): "lock"}
_FUSE_WRITES = {0xA0: "lfuse", 0xA8: "hfuse", 0xA4: "efuse"}


# -- the programmer ---------------------------------------------------------------------------------
class Line(Protocol):
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


# STK500 v1 (Atmel AVR061)
EOP = 0x20
INSYNC, OK, FAILED, UNKNOWN, NOSYNC = 0x14, 0x10, 0x11, 0x12, 0x15
GET_SYNC, GET_SIGN_ON, SET_PARAMETER, GET_PARAMETER = 0x30, 0x31, 0x40, 0x41
SET_DEVICE, SET_DEVICE_EXT, ENTER_PROGMODE, LEAVE_PROGMODE = 0x42, 0x45, 0x50, 0x51
CHIP_ERASE, LOAD_ADDRESS, UNIVERSAL = 0x52, 0x55, 0x56
PROG_PAGE, READ_PAGE, READ_SIGN = 0x64, 0x74, 0x75
SCK_DURATION = 0x89
#: The STK500's controller clock: one SCK_DURATION step is 8 of its cycles.
STK500_XTAL = 7_372_800
#: The STK500 keeps its SCK setting; the stand-in starts with what ``-B 8`` sets (7, 7.6 us),
#: since avrdude before 7.3 never sends ``-B`` to an stk500v1 (only its terminal's ``sck``).
SCK_DURATION_START = int(ISP_BITCLOCK_US * 1e-6 * STK500_XTAL / 8 + 0.5)
#: Length of each fixed-size command, EOP included; PROG_PAGE and SET_DEVICE_EXT carry theirs.
_LENGTHS = {GET_SYNC: 2, GET_SIGN_ON: 2, SET_PARAMETER: 4, GET_PARAMETER: 3, SET_DEVICE: 22,
            ENTER_PROGMODE: 2, LEAVE_PROGMODE: 2, CHIP_ERASE: 2, LOAD_ADDRESS: 4, UNIVERSAL: 6,
            READ_PAGE: 5, READ_SIGN: 2}


class Stk500Programmer:
    """An STK500 (firmware 1.18) with ``chip`` in its socket, answering on ``line``.

    Call :meth:`start` (or use it as a context manager); avrdude then finds it at
    :attr:`path` with ``-c stk500v1 -p m162``. ``parameters`` are the STK500's (hardware
    2, firmware 1.18, 5.0 V, SCK duration :data:`SCK_DURATION_START`).
    """

    def __init__(self, line: Line, chip: Atmega162 | None = None) -> None:
        self.line = line
        self.chip = chip if chip is not None else Atmega162()
        self.parameters = {0x80: 2, 0x81: 1, 0x82: 18, 0x83: 0, 0x84: 50, 0x85: 50, 0x86: 0,
                           0x87: 1, 0x88: 0, SCK_DURATION: SCK_DURATION_START, 0x98: 3}
        self.device_code: int | None = None  # what avrdude's SET_DEVICE said the part is
        #: From the first command this says True to, the programmer answers nothing more (it
        #: hung, or its cable was pulled) while avrdude goes on: a silent programmer, for tests.
        self.silent_from: Callable[[bytes], bool] | None = None
        self.silent = False
        self.progmode = False
        self.commands = 0
        self._address = 0
        self._rx = bytearray()
        self._closing = False
        self._thread: threading.Thread | None = None

    @classmethod
    def on_pty(cls, link: str | os.PathLike[str] | None = None,
               chip: Atmega162 | None = None) -> "Stk500Programmer":
        """A programmer behind a new pty (a symlink to it at ``link``)."""
        from .pty import Pty

        return cls(Pty(link), chip)

    @property
    def path(self) -> str:
        """What to give avrdude's ``-P``: the pty's link or device."""
        return str(getattr(self.line, "path", ""))

    @property
    def sck_hz(self) -> float:
        return STK500_XTAL / (8 * max(1, self.parameters[SCK_DURATION]))

    # -- life ---------------------------------------------------------------------------------------
    def start(self) -> "Stk500Programmer":
        self._thread = threading.Thread(target=self._run, name="stk500-standin", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop answering and close the line; idempotent."""
        self._closing = True
        if self._thread is not None:
            self._thread.join(timeout=5)
        self.line.close()

    def __enter__(self) -> "Stk500Programmer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def _run(self) -> None:
        while not self._closing:
            try:
                data = self.line.read(4096)
            except OSError:  # the line closed under us
                return
            if data:
                self.feed(data)

    # -- the protocol -------------------------------------------------------------------------------
    def feed(self, data: bytes) -> None:
        """Take bytes from the line; answer every complete command."""
        rx = self._rx
        rx += data
        while rx:
            n = self._length(rx)
            if n is None or len(rx) < n:
                return
            command = bytes(rx[:n])
            del rx[:n]
            if not self.silent and self.silent_from is not None and self.silent_from(command):
                self.silent = True
            if not self.silent:
                self.line.write(self.answer(command))

    @staticmethod
    def _length(rx: bytearray) -> int | None:
        """Bytes of the command at the head of ``rx`` (None: more are needed to tell)."""
        op = rx[0]
        if op in _LENGTHS:
            return _LENGTHS[op]
        if op == PROG_PAGE:
            return 5 + (rx[1] << 8 | rx[2]) if len(rx) >= 3 else None
        if op == SET_DEVICE_EXT:
            return 2 + rx[1] if len(rx) >= 2 else None
        return 2  # unknown: answered once its EOP is there

    def answer(self, command: bytes) -> bytes:
        """The STK500's answer to one whole command (EOP included)."""
        if command[-1] != EOP:
            return bytes((NOSYNC,))
        self.commands += 1
        op, args = command[0], command[1:-1]
        if op == GET_SIGN_ON:
            return bytes((INSYNC,)) + b"AVR STK" + bytes((OK,))
        if op == GET_PARAMETER:
            value = self.parameters.get(args[0])
            return bytes((INSYNC, 0, FAILED) if value is None else (INSYNC, value, OK))
        if op == UNIVERSAL:
            return bytes((INSYNC, self.chip.spi(args), OK))
        if op == READ_SIGN:
            return bytes((INSYNC,)) + bytes(self.chip.spi(bytes((0x30, 0, i, 0))) for i in range(3)) + bytes((OK,))
        if op == READ_PAGE:
            data = self._page(args[2], args[0] << 8 | args[1])
            return bytes((INSYNC,)) + data + bytes((OK,)) if data is not None else bytes((INSYNC, FAILED))
        if op not in _LENGTHS and op not in (PROG_PAGE, SET_DEVICE_EXT):
            return bytes((INSYNC, UNKNOWN))
        return bytes((INSYNC, self._do(op, args)))

    def _do(self, op: int, args: bytes) -> int:
        """Commands that answer only OK or an error byte."""
        if op == SET_PARAMETER:
            self.parameters[args[0]] = args[1]
        elif op == SET_DEVICE:
            self.device_code = args[0]
        elif op == ENTER_PROGMODE:
            # the chip samples SCK with its own clock: above a quarter of it, it hears nothing
            if self.sck_hz >= self.chip.cpu_hz / 4:
                return FAILED
            self.progmode = True
        elif op == LEAVE_PROGMODE:
            self.progmode = False
        elif op == CHIP_ERASE:
            self.chip.chip_erase()
        elif op == LOAD_ADDRESS:
            self._address = args[0] | args[1] << 8
        elif op == PROG_PAGE:
            data, memtype = args[3:], args[2]
            if memtype == ord("F"):
                self.chip.write_flash(self._address * 2, data)
            elif memtype == ord("E"):
                self.chip.write_eeprom(self._address, data)
            else:
                return FAILED
        return OK

    def _page(self, memtype: int, size: int) -> bytes | None:
        if memtype == ord("F"):
            start, memory = self._address * 2, "flash"
        elif memtype == ord("E"):
            start, memory = self._address, "eeprom"
        else:
            return None
        return bytes(self.chip.read(memory, start + i) for i in range(size))


__all__ = ["Atmega162", "EmptySocket", "FACTORY_FUSES", "MEMORY_SIZES", "Stk500Programmer", "format_ihex",
           "fuses_of", "fuses_text", "parse_ihex", "read_ihex"]

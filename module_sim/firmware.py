"""The C firmware as a virtual module's program (Kilombo's way: the robot's own code, compiled
for the host, run inside the simulator).

``make -C firmware host`` builds each board's program (the same ``.c`` files as the
ATmega162 image) with a host board layer as a shared library. A :class:`FirmwareDriver`
runs one board's copy of it on an :class:`~module_sim.avr.Mcu` in place of the Python
program: on every event (power-up, a byte received, a wake-up the program asked for) it
hands the library the time, the received bytes and the input pins, runs one step, and
replays what the program did, in order: port writes through the Mcu (so the world, the LEDs
and the multiplexer see them as from the Python programs) and transmissions through the
UARTs' hooks (so frames, IR bursts and the other board's UART0 see them too).

One library serves every board of its kind: all the program's memory is one block that
each driver keeps a copy of and the step swaps in and out (firmware/host/board_host.c).

A step that makes more events than the library's buffers hold (HEXBOT_MAX_EVENTS,
HEXBOT_MAX_BYTES) hands them over on the way (``hexbot_flush``): the driver replays them at
once and the step goes on. Nothing is lost; should the library ever count a lost event
(``hexbot_io.overflow``), the step fails with a :class:`FirmwareError` naming the board.
"""

from __future__ import annotations

import ctypes
import struct
from pathlib import Path
from typing import Callable

from bus.cheader import BUILD_DIR, FirmwareError, build_path, ensure_built, ensure_fresh
from bus.pins import OPTICAL_SWITCH, PORTS, port_masks, switch_levels

from .avr import Mcu

_EV_PORT, _EV_TX = 1, 2
_EVENT = struct.Struct("<BBBBHH")  # hexbot_event_t
_MAX_EVENTS, _MAX_BYTES = 256, 1024
_FLUSH = ctypes.CFUNCTYPE(None)  # hexbot_flush_fn
#: The optical switches' bits of each port (the levels of the other input pins stay as set).
_SWITCH_BITS = port_masks(list(OPTICAL_SWITCH.values()))


class _Event(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_uint8), ("a", ctypes.c_uint8), ("n", ctypes.c_uint8),
                ("pad", ctypes.c_uint8), ("offset", ctypes.c_uint16), ("pad2", ctypes.c_uint16)]


class _Io(ctypes.Structure):
    """hexbot_io_t of firmware/host/hexbot_host.h."""

    _fields_ = [("wake", ctypes.c_uint64), ("rx", (ctypes.c_uint8 * 4) * 2),
                ("rx_n", ctypes.c_uint8 * 2), ("rx_used", ctypes.c_uint8 * 2),
                ("n_events", ctypes.c_uint16), ("n_bytes", ctypes.c_uint16),
                ("overflow", ctypes.c_uint16), ("pad", ctypes.c_uint16),
                ("events", _Event * _MAX_EVENTS), ("bytes", ctypes.c_uint8 * _MAX_BYTES),
                ("starts", ctypes.c_uint64 * _MAX_BYTES)]


class Program:
    """One board's program in one profile: the loaded host library (``path``: another
    library built with the host board layer, e.g. a test's)."""

    _loaded: dict[tuple[str, str], "Program"] = {}

    def __init__(self, board: str, profile: str, path: Path | None = None) -> None:
        if path is None:
            path = build_path("lib", board, profile)
            if not path.exists():
                ensure_built()
            elif path.parent == BUILD_DIR:
                ensure_fresh("host")
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise FirmwareError(f"cannot load the firmware's host library {path}: {exc}") from None
        lib.hexbot_state_size.restype = ctypes.c_size_t
        lib.hexbot_setup.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint32,
                                     ctypes.c_uint32]
        lib.hexbot_set_pins.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.hexbot_step.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
        for f in (lib.hexbot_setup, lib.hexbot_set_pins, lib.hexbot_step):
            f.restype = None
        self.lib = lib
        self.setup, self.set_pins, self.step = lib.hexbot_setup, lib.hexbot_set_pins, lib.hexbot_step
        self.io = _Io.in_dll(lib, "hexbot_io")
        self.events = memoryview(self.io.events).cast("B")  # 8 bytes an event
        #: the driver whose step runs (the library's buffers are its events until replayed)
        self.stepping: FirmwareDriver | None = None
        self._flush = _FLUSH(self._flushed)  # kept: the library calls it
        try:
            hook = ctypes.c_void_p.in_dll(lib, "hexbot_flush")
        except ValueError:
            raise FirmwareError(f"{path} is older than firmware/host (no hexbot_flush): "
                                "make -C firmware host") from None
        hook.value = ctypes.cast(self._flush, ctypes.c_void_p).value
        self.size = lib.hexbot_state_size()
        self.power_on = ctypes.create_string_buffer(self.size)
        lib.hexbot_state_init(self.power_on)  # before any step: the image at power-up

    def _flushed(self) -> None:
        """The library's buffers are full in the middle of a step: replay what they hold."""
        driver = self.stepping
        if driver is not None and driver._failure is None:
            try:
                driver._replay()
            except BaseException as exc:  # raised again once the step returns (not into C)
                driver._failure = exc

    @classmethod
    def get(cls, board: str, profile: str) -> "Program":
        key = (board, profile)
        if key not in cls._loaded:
            cls._loaded[key] = cls(board, profile)
        return cls._loaded[key]


def input_pins(mcu: Mcu, switches: list[bool] | None) -> bytes:
    """The levels on ``mcu``'s input pins, PORTA..PORTE: what it reads from its DIP
    switches, and the optical switches of a comm board (``switches``: neighbours on body
    sides 1..6) on the pins of :data:`bus.pins.OPTICAL_SWITCH`."""
    pins = [mcu.pin_in[letter] for letter in PORTS]
    if switches is not None:
        levels = switch_levels(switches)
        for k, letter in enumerate(PORTS):
            pins[k] = pins[k] & ~_SWITCH_BITS[letter] & 0xFF | levels.get(letter, 0)
    return bytes(pins)


class FirmwareDriver:
    """Runs ``program`` as ``mcu``'s program. ``switches()`` gives the optical switches (comm
    board); they are read on the pins of :data:`bus.pins.OPTICAL_SWITCH`."""

    def __init__(self, mcu: Mcu, program: Program,
                 switches: Callable[[], list[bool]] | None = None) -> None:
        self.mcu = mcu
        self.program = program
        self.switches = switches
        self.state = ctypes.create_string_buffer(program.power_on.raw, program.size)
        self._uarts = (mcu.uart0, mcu.uart1)
        self._pins = (ctypes.c_uint8 * 5)()
        self._state = ctypes.addressof(self.state)
        self._timer = None
        self._wake_at = 0
        self._failure: BaseException | None = None
        self.steps = 0

    def power_up(self) -> None:
        mcu = self.mcu
        mcu._boot_ns = mcu.clock.now_ns()
        mcu.driver = self
        self.program.setup(self._state, mcu._boot_ns, self._uarts[0].byte_ns, self._uarts[1].byte_ns)
        self.refresh_pins()
        self.step()

    def refresh_pins(self) -> None:
        """Hand the program its input pins (DIP switches, optical switches): at power-up and
        whenever the module's switches change (VirtualModule calls it)."""
        self._pins[:] = input_pins(self.mcu, None if self.switches is None else self.switches())
        self.program.set_pins(self._state, self._pins)

    def step(self) -> None:
        """Run the program until it waits; replay what it did; ask to be woken."""
        mcu, prog = self.mcu, self.program
        if mcu.halted:
            return
        io = prog.io
        uart0, uart1 = self._uarts
        rx0, rx1 = uart0._rx, uart1._rx
        if rx0:
            io.rx_n[0] = n = min(len(rx0), 4)
            for k in range(n):
                io.rx[0][k] = rx0[k]
        if rx1:
            io.rx_n[1] = n = min(len(rx1), 4)
            for k in range(n):
                io.rx[1][k] = rx1[k]
        prog.stepping = self
        try:
            prog.step(self._state, mcu.clock.now_ns())
        finally:
            prog.stepping = None
        self.steps += 1
        failure, self._failure = self._failure, None
        if failure is not None:
            raise failure
        if io.overflow:
            raise FirmwareError(f"{mcu.name}: the firmware's step made more events than the host "
                                f"board layer holds; {io.overflow} lost (firmware/host/board_host.c)")
        used = io.rx_used
        for _ in range(used[0]):
            rx0.popleft()
        for _ in range(used[1]):
            rx1.popleft()
        self._replay()
        wake = io.wake
        if wake != self._wake_at:  # a new wake-up time (an unchanged one stays booked)
            if self._timer is not None:
                self._timer.cancel()
            self._timer = mcu.clock.call_at(wake, self._woken) if wake else None
            self._wake_at = wake

    def _replay(self) -> None:
        """What the program did, in order: port writes through the Mcu, transmissions
        through the UARTs' hooks."""
        io, prog = self.program.io, self.program
        n = io.n_events
        if n:
            for kind, a, v, _, offset, _ in _EVENT.iter_unpack(prog.events[:8 * n]):
                if kind == _EV_PORT:
                    self.mcu.firmware_port_write(PORTS[a], v)
                else:
                    hook = self._uarts[a].on_tx
                    if hook is not None:
                        hi = offset + v
                        hook(bytes(io.bytes[offset:hi]), io.starts[offset:hi])

    def _woken(self) -> None:
        self._timer = None
        self._wake_at = 0
        self.step()

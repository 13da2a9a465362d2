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
"""

from __future__ import annotations

import ctypes
from typing import Callable

from bus.cheader import FirmwareError, build_path, ensure_built
from bus.pins import OPTICAL_SWITCH, PORTS

from .avr import Mcu

_EV_PORT, _EV_TX = 1, 2
_MAX_EVENTS, _MAX_BYTES = 256, 1024


class _Event(ctypes.Structure):
    _fields_ = [("kind", ctypes.c_uint8), ("a", ctypes.c_uint8), ("n", ctypes.c_uint8),
                ("pad", ctypes.c_uint8), ("offset", ctypes.c_uint16), ("pad2", ctypes.c_uint16)]


class _Io(ctypes.Structure):
    """hexbot_io_t of firmware/host/hexbot_host.h."""

    _fields_ = [("wake", ctypes.c_uint64), ("rx", (ctypes.c_uint8 * 4) * 2),
                ("rx_n", ctypes.c_uint8 * 2), ("rx_used", ctypes.c_uint8 * 2),
                ("n_events", ctypes.c_uint16), ("n_bytes", ctypes.c_uint16),
                ("events", _Event * _MAX_EVENTS), ("bytes", ctypes.c_uint8 * _MAX_BYTES),
                ("starts", ctypes.c_uint64 * _MAX_BYTES)]


class Program:
    """One board's program in one profile: the loaded host library."""

    _loaded: dict[tuple[str, str], "Program"] = {}

    def __init__(self, board: str, profile: str) -> None:
        path = build_path("lib", board, profile)
        if not path.exists():
            ensure_built()
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise FirmwareError(f"cannot load the firmware's host library {path}: {exc}") from None
        lib.hexbot_state_size.restype = ctypes.c_size_t
        lib.hexbot_step.argtypes = [ctypes.c_void_p, ctypes.c_uint64, ctypes.c_uint64,
                                    ctypes.c_uint32, ctypes.c_uint32, ctypes.c_void_p]
        lib.hexbot_step.restype = None
        self.step = lib.hexbot_step
        self.io = _Io.in_dll(lib, "hexbot_io")
        self.size = lib.hexbot_state_size()
        self.power_on = ctypes.create_string_buffer(self.size)
        lib.hexbot_state_init(self.power_on)  # before any step: the image at power-up

    @classmethod
    def get(cls, board: str, profile: str) -> "Program":
        key = (board, profile)
        if key not in cls._loaded:
            cls._loaded[key] = cls(board, profile)
        return cls._loaded[key]


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
        self._timer = None
        self.steps = 0

    def power_up(self) -> None:
        self.mcu._boot_ns = self.mcu.clock.now_ns()
        self.mcu.driver = self
        self.step()

    def step(self) -> None:
        """Run the program until it waits; replay what it did; ask to be woken."""
        mcu, prog = self.mcu, self.program
        if mcu.halted:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        io = prog.io
        for u, uart in enumerate(self._uarts):
            waiting = uart._rx
            n = min(len(waiting), 4)
            for k in range(n):
                io.rx[u][k] = waiting[k]
            io.rx_n[u] = n
        pins = self._pins
        for k, letter in enumerate(PORTS):
            pins[k] = mcu.pin_in[letter]
        if self.switches is not None:
            for side, present in enumerate(self.switches(), start=1):
                pin = OPTICAL_SWITCH[side]
                if present:
                    pins[PORTS.index(pin.port)] |= pin.mask
        now = mcu.clock.now_ns()
        prog.step(self.state, now, mcu._boot_ns, self._uarts[0].byte_ns, self._uarts[1].byte_ns,
                  pins)
        self.steps += 1
        for u, uart in enumerate(self._uarts):
            for _ in range(io.rx_used[u]):
                uart._rx.popleft()
        events, data, starts = io.events, io.bytes, io.starts
        for i in range(io.n_events):
            e = events[i]
            if e.kind == _EV_PORT:
                mcu.firmware_port_write(PORTS[e.a], e.n)
            else:
                hook = self._uarts[e.a].on_tx
                if hook is not None:
                    lo, hi = e.offset, e.offset + e.n
                    hook(bytes(data[lo:hi]), list(starts[lo:hi]))
        if io.wake:
            self._timer = mcu.clock.call_at(io.wake, self.step)

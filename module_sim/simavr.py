"""The flashed images in simavr as a virtual module's program (``program = "simavr"``).

``firmware/simavr/hexbot_lib.c`` (``libhexbot-simavr.so``, built beside the harness) runs both
ATmega162 cores of a module in-process, on our ATmega162 core, with their UART0s wired
together. A :class:`SimavrDriver` drives one module's pair on the run's clock, in place of
the Python programs or the host-built C programs, and keeps everything around them
unchanged: the boards' :class:`~module_sim.avr.Mcu` objects carry the ports (so the world,
the LEDs, the actuators and the IR multiplexer see the chip's port writes), the UART hooks
carry what the chip sends (frames, IR bursts, the debug line), the IR medium brings light in.

**Time.** Cycle ``c`` of a module's cores is sim time ``power-up + c * 1000 ns`` (1 MHz).
The cores run ahead of the run's clock, conservatively (Avrora's lookahead): no byte can
reach a module less than one IR byte time after its burst was published (a window less on a
lockstep clock, whose samples from other processes arrive up to a window late), so the cores
run to ``now + lookahead``, or to the end of the next byte already on its way to the module,
whichever is first. What they did meanwhile (a byte's start bit, a port write) is booked on
the clock at its own cycle's time and happens then, as from the other programs; a byte that
reaches the comm board's UART1 goes into the core at its stop bit, with the core exactly there.

**Optical switches** change on the pins :data:`SWITCH_DELAY_NS` after the world says so: the
cores may be up to a lookahead ahead of the clock, and a fixed delay keeps the moment the same
whatever the lookahead (one process or shards). The DIP switches are the module's id.

Errors (no libsimavr, an image that is missing or not an ATmega162 ELF, a core that crashes)
are :class:`~bus.cheader.FirmwareError`: one line.
"""

from __future__ import annotations

import ctypes
import heapq
import json
import weakref
from typing import Any

from bus.cheader import BUILD_DIR, F_CPU, FirmwareError, build_path, ensure_built, ensure_fresh, ubrr
from bus.codec import Link
from bus.pins import DIP_PORT, PORTS, dip_id
from bus.timing import BITS_PER_BYTE, NS_PER_S, Baud, byte_time_ns

NS_PER_CYCLE = NS_PER_S // F_CPU
#: The chip's IR byte: ten bits at the UBRR-exact rate (33.28 ms at 300 baud nominal).
CHIP_IR_BYTE_NS = BITS_PER_BYTE * 16 * (ubrr(Baud.IR) + 1) * NS_PER_CYCLE
#: How long after the world changes them the optical switches read so on the comm board's pins.
SWITCH_DELAY_NS = byte_time_ns(Baud.IR)

LIB_NAME = "libhexbot-simavr.so"
_ABI = 1
_EV_TX, _EV_PORT, _EV_OVERRUN, _EV_HALT = 1, 2, 3, 4
_COMM, _CONTROL = 0, 1
_BATCH = 1024


class _Event(ctypes.Structure):
    """hbl_event_t of firmware/simavr/hexbot_lib.c."""

    _fields_ = [("t", ctypes.c_uint64), ("kind", ctypes.c_uint8), ("board", ctypes.c_uint8),
                ("unit", ctypes.c_uint8), ("value", ctypes.c_uint8), ("frame", ctypes.c_uint32)]


_lib: ctypes.CDLL | None = None


def library() -> ctypes.CDLL:
    """``libhexbot-simavr.so``, loaded once (built with the firmware if it is missing)."""
    global _lib
    if _lib is not None:
        return _lib
    path = BUILD_DIR / LIB_NAME
    if not path.exists():
        ensure_built()
    if not path.exists():
        raise FirmwareError(f"{path} is not built: make -C firmware simavr (needs libsimavr-dev)")
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:  # libsimavr.so.2 gone since the build, say
        raise FirmwareError(f"cannot load {path}: {exc} (install simavr: .ci/system)") from None
    if not hasattr(lib, "hbl_abi") or lib.hbl_abi() != _ABI \
            or lib.hbl_event_size() != ctypes.sizeof(_Event):
        raise FirmwareError(f"{path} does not match module_sim/simavr.py: make -C firmware simavr")
    h = ctypes.c_void_p
    lib.hbl_new.restype = h
    lib.hbl_new.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_int,
                            ctypes.c_char_p, ctypes.c_size_t]
    lib.hbl_free.argtypes = [h]
    lib.hbl_free.restype = None
    lib.hbl_error.argtypes = [h]
    lib.hbl_error.restype = ctypes.c_char_p
    lib.hbl_run.argtypes = [h, ctypes.c_uint64]
    lib.hbl_halt.argtypes = [h, ctypes.c_int]
    lib.hbl_halt.restype = None
    lib.hbl_rx.argtypes = [h, ctypes.c_int, ctypes.c_int, ctypes.c_uint8, ctypes.c_uint64,
                           ctypes.c_uint32, ctypes.c_uint32]
    lib.hbl_rx.restype = None
    lib.hbl_switches_at.argtypes = [h, ctypes.c_int, ctypes.c_uint64]
    lib.hbl_take.argtypes = [h, ctypes.c_uint64, ctypes.POINTER(_Event), ctypes.c_size_t]
    lib.hbl_take.restype = ctypes.c_size_t
    lib.hbl_now.argtypes = [h]
    lib.hbl_now.restype = ctypes.c_uint64
    for f in (lib.hbl_frame_cycles, lib.hbl_bit_cycles):
        f.argtypes = [h, ctypes.c_int, ctypes.c_int]
        f.restype = ctypes.c_uint32
    _lib = lib
    return lib


def _switch_mask(present: list[bool]) -> int:
    return sum(1 << k for k, p in enumerate(present) if p)


class SimavrDriver:
    """Both boards of ``module`` as the images of its profile in simavr. Made with the module
    (a missing image or library fails there, before the run); :meth:`power_up` starts it."""

    def __init__(self, module: Any) -> None:
        """``module``: the :class:`~module_sim.module.VirtualModule` (not imported: it imports
        this module)."""
        self.module = module
        self.clock = module.bus.clock
        lib = self.lib = library()
        profile = module.ctrl.profile.name
        images = [build_path("elf", board, profile) for board in ("comm", "control")]
        if not all(p.exists() for p in images):
            ensure_built()
        else:
            ensure_fresh("images")
        err = ctypes.create_string_buffer(256)
        dip = dip_id(module.ctrl.pin_in[DIP_PORT])
        handle = lib.hbl_new(str(images[0]).encode(), str(images[1]).encode(), dip,
                             _switch_mask(module.switches), err, len(err))
        if not handle:
            raise FirmwareError(f"{module.name} (simavr): {err.value.decode(errors='replace')}")
        self.handle = handle
        weakref.finalize(self, lib.hbl_free, handle)
        self._events = (_Event * _BATCH)()
        self.boot_ns = 0
        self._due: list[int] = []  # stop bits of IR bytes on their way here
        self._again = False
        self._timer = None
        self._timer_at = -1
        self._ctrl_halted = False
        self.syncs = 0
        comm, ctrl = module.comm, module.ctrl
        # UART0 frames, as VirtualModule._wire publishes them (the bytes themselves cross inside)
        self._uart0 = (module._framer_publisher(Link.UART0_DOWN, comm.name, ctrl.name),
                       module._framer_publisher(Link.UART0_UP, ctrl.name, comm.name))
        self._mcus = (comm, ctrl)
        self._uart1 = (comm.uart1, ctrl.uart1)
        self._rx_frame = ctypes.c_uint32(CHIP_IR_BYTE_NS // NS_PER_CYCLE)
        self._rx_bit = ctypes.c_uint32(self._rx_frame.value // BITS_PER_BYTE)
        module.bus.subscribe(module.bus.keys.ir_rx(module.name), self._on_light)

    # -- the module's side ---------------------------------------------------------------------
    def power_up(self) -> None:
        now = self.clock.now_ns()
        self.boot_ns = now
        for mcu in self._mcus:
            mcu._boot_ns = now
            mcu.driver = self
        # the switches the world said before power-up (from now on: refresh_pins)
        self.lib.hbl_switches_at(self.handle, _switch_mask(self.module.switches), 0)
        self._advance()

    def refresh_pins(self) -> None:
        """The optical switches changed (VirtualModule._on_switches)."""
        at = self.clock.now_ns() + SWITCH_DELAY_NS - self.boot_ns
        if self.lib.hbl_switches_at(self.handle, _switch_mask(self.module.switches),
                                    at // NS_PER_CYCLE) < 0:
            raise FirmwareError(f"{self.module.name} (simavr): optical switches change too often")

    def step(self) -> None:
        """A byte reached a receiver (Mcu._rx_ready): into the core at its stop bit, now."""
        now = self.clock.now_ns()
        cycle = (now - self.boot_ns) // NS_PER_CYCLE
        for board, mcu in enumerate(self._mcus):
            for n, uart in enumerate((mcu.uart0, mcu.uart1)):
                rx = uart._rx
                while rx:
                    self.lib.hbl_rx(self.handle, board, n, rx.popleft(), cycle, self._rx_frame,
                                    self._rx_bit)
        if self._timer_at != now:  # run on from here once every delivery of this instant is in
            self._book(now)

    # -- time ------------------------------------------------------------------------------------
    def _on_light(self, key: str, payload: bytes) -> None:
        d = json.loads(payload)
        if d.get("type") != "burst":
            return  # a cut or a garble changes bytes, not when they end
        byte_ns = d["byte_ns"]
        for s in d["starts"]:
            heapq.heappush(self._due, s + byte_ns)

    def _lookahead(self) -> int:
        step = getattr(self.clock, "lockstep", None)
        late = step.window_ns if step is not None else 0
        return max(min(byte_time_ns(self.module.comm.uart1.baud), CHIP_IR_BYTE_NS) - late, 1000)

    def _book(self, t: int) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.clock.call_at(t, self._advance)
        self._timer_at = t

    def _advance(self) -> None:
        self._timer = None
        self._timer_at = -1
        now = self.clock.now_ns()
        due = self._due
        if due and due[0] <= now and not self._again:
            # bytes end now: let their deliveries (booked before this) run first
            self._again = True
            self._book(now)
            return
        self._again = False
        while due and due[0] <= now:
            heapq.heappop(due)
        horizon = now + self._lookahead()
        if due and due[0] < horizon:
            horizon = due[0]
        self._run(horizon)
        self._book(horizon)

    def _run(self, until_ns: int) -> None:
        lib, h = self.lib, self.handle
        if self.module.ctrl.halted and not self._ctrl_halted:  # a test's board that never answers
            self._ctrl_halted = True
            lib.hbl_halt(h, _CONTROL)
        until = -(-(until_ns - self.boot_ns) // NS_PER_CYCLE)
        if lib.hbl_run(h, until) < 0:
            raise FirmwareError(f"{self.module.name} (simavr): {lib.hbl_error(h).decode()}")
        self.syncs += 1
        now = self.clock.now_ns()
        boot, call_at, emit, events = self.boot_ns, self.clock.call_at, self._emit, self._events
        while True:
            n = lib.hbl_take(h, ~0 & 0xFFFF_FFFF_FFFF_FFFF, events, _BATCH)
            for i in range(n):
                e = events[i]
                t = boot + e.t * NS_PER_CYCLE
                call_at(t if t > now else now, emit, t, e.kind, e.board, e.unit, e.value, e.frame)
            if n < _BATCH:
                break

    def _emit(self, t: int, kind: int, board: int, unit: int, value: int, frame: int) -> None:
        if kind == _EV_PORT:
            self._mcus[board].firmware_port_write(PORTS[unit], value)
        elif kind == _EV_TX:
            byte_ns = frame * NS_PER_CYCLE
            if unit == 0:
                self._uart0[board](bytes((value,)), [t], byte_ns)
            else:
                uart = self._uart1[board]
                uart.byte_ns = byte_ns  # the chip's UBRR-exact byte time on its wire
                if uart.on_tx is not None:
                    uart.on_tx(bytes((value,)), [t])
        elif kind == _EV_OVERRUN:
            mcu = self._mcus[board]
            uart = mcu.uart1 if unit else mcu.uart0
            uart.overruns += 1
            if uart.on_overrun is not None:
                uart.on_overrun(value)
        elif kind == _EV_HALT:
            self._mcus[board].halted = True

"""The fleet core: the virtual modules' boards and the world's IR medium in one compiled loop.

:class:`FleetCore` runs every firmware-program virtual module of a fleet (both boards, the
UART0 line between them, the multiplexer) and all IR light (core.c). Python enters it once
per *window* on the virtual clock: a window runs every core event before the next Python
timer and ends early, at the end of an instant, when something outside must act:

* a coil changed (a solenoid or magnet bit of a control board's port) that the mechanics
  must judge now: any, while a body of the fleet moves or a module tries to (a magnet pair
  on); while the world is at rest only one that makes a magnet pair or a relay fight, since
  no other can start anything (the judge's short way) and is judged the same at the
  window's end, in time order; none in a world without physics;
* a byte reached a receiver outside the core (the PC's, a twin's): it goes out on
  ``ir/rx/<dst>`` now, and that receiver delivers it at once.

What else the window made comes out in bulk at its end, each sample stamped with its own
instant: the records of other port changes (LEDs, the multiplexer: nothing the mechanics acts
on), UART overruns, collisions (``event/world``), and every byte on every wire framed and
published in the order the frames' last bytes end (a frame is published once the window has
passed its end, as a Python module's is at its end). Light from outside the core (the PC,
twins) enters the same medium (:meth:`put_light`), so the IR medium exists once.

The geometry stays in Python: the world tells the core which receiver each transceiver's
light reaches (:meth:`routes_changed`), recomputed when a body moves.
"""

from __future__ import annotations

import ctypes
import itertools
import json
import subprocess
import threading
import weakref
from pathlib import Path
from time import perf_counter_ns
from typing import TYPE_CHECKING, Any

import numpy as np

from bus.cheader import FirmwareError, build_path
from bus.codec import Link
from bus.framer import Framer, patterns
from bus.ir import burst_light, burst_tail, one_byte_burst
from bus.keys import PC, WORLD, module_endpoint
from bus.pins import IR_SEL_A, MAGNET_NEG, MAGNET_POS, PORTS, ir_selected
from bus.envelope import Envelope
from bus.transport import Bus, frame_json_names, frame_json_parts, pack_batch

from ..control_board import COIL_MASK
from ..firmware import Program

if TYPE_CHECKING:
    from ..module import VirtualModule
    from ..world import World

HERE = Path(__file__).resolve().parent
LIB = HERE / "build" / "libhexcore.so"
#: The longest window with no Python timer to stop it (a run's ``until`` is checked between).
MAX_WINDOW_NS = 100_000_000
_NO_TIME = 2**64 - 1
_OUT_TX, _OUT_PORTS, _OUT_RX, _OUT_OVERRUN, _OUT_COLLISION = 1, 2, 3, 4, 5
#: a link's number in the core (its whole-write map's key)
_LINKS = list(Link)
#: what the core's frames say of their origin (Envelope's default, as frame_sample gave them)
_ORIGIN = Envelope.__dataclass_fields__["origin"].default
#: distinct frames whose parts Python remembers (each also in the core); the others' parts
#: serve one frame each
_PARTS_MAX = 1 << 16
#: core.c core_add_parts' uses
_PARTS_KEPT, _PARTS_WHOLE, _PARTS_ONCE = 0, 1, 2
#: core.c COIL_*: what a module's coil change means to the window
_COIL_STOP, _COIL_MAGNETS, _COIL_FREE = 0, 1, 2
#: out_t of core.c
_OUT = np.dtype([("t", "<u8"), ("aux", "<u8"), ("kind", "<u4"), ("m", "<u4"), ("a", "<i4"),
                 ("b", "<i4"), ("n", "<i4"), ("off", "<u4"), ("off2", "<u4"), ("n2", "<u4")])
_lock = threading.Lock()
#: core_put_light's answers (core.c LIGHT_*)
_LIGHT_REFUSED = {1: "its start times or corrupt flags do not match its bytes", 2: "unknown source",
                  3: "unknown receiver", 4: "a zero byte time", 5: "a byte ends past the clock's range"}


def _library() -> ctypes.CDLL:
    """libhexcore.so, built with ``make -C module_sim/core`` when missing or older than its
    sources."""
    with _lock:
        sources = [HERE / "core.c", HERE / "Makefile"]
        header = HERE.parent.parent / "firmware" / "host" / "hexbot_host.h"
        if header.exists():
            sources.append(header)
        stale = not LIB.exists() or any(s.exists() and s.stat().st_mtime > LIB.stat().st_mtime
                                        for s in sources)
        if stale and (HERE / "core.c").exists():
            try:
                subprocess.run(["make", "-s", "-C", str(HERE)], check=True, capture_output=True, text=True)
            except FileNotFoundError:
                raise FirmwareError("the fleet core is built with make and a C compiler: "
                                    "apt-get install build-essential") from None
            except subprocess.CalledProcessError as exc:
                last = (exc.stderr or exc.stdout or "").strip().splitlines()[-1:] or ["?"]
                raise FirmwareError(f"make -C {HERE} failed: {last[0]}") from None
        if not LIB.exists():
            raise FirmwareError(f"the fleet core library {LIB} is missing (make -C module_sim/core)")
        lib = ctypes.CDLL(str(LIB))
    p, u32, u64, i32 = ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint64, ctypes.c_int32
    lib.core_new.restype = p
    lib.core_new.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, p, u32,
                             ctypes.c_char_p]
    lib.core_add_modules.restype = u32
    lib.core_add_modules.argtypes = [p, u32]
    lib.core_receiver.restype = i32
    lib.core_receiver.argtypes = [p, u32, u32]
    for name in ("core_add_external_receiver", "core_add_external_source"):
        getattr(lib, name).restype = i32
        getattr(lib, name).argtypes = [p]
    lib.core_error.restype = ctypes.c_char_p
    lib.core_error.argtypes = [p]
    lib.core_free.argtypes = [p]
    lib.core_set_route.argtypes = [p, u32, u32, i32]
    lib.core_set_magnet_pins.argtypes = [p, ctypes.c_char_p]
    cp = ctypes.c_char_p
    lib.core_set_wire.argtypes = [p, u32, u32, u32, u32, cp, u32, cp, u32, cp, u32]
    lib.core_wire_empty.argtypes = [p, u32, u32, u32]
    lib.core_add_parts.restype = u32
    lib.core_add_parts.argtypes = [p, u32, cp, u32, u32, cp, u32, cp, u32, cp, u32]
    lib.core_queue_frame.argtypes = [p, u32, u32, u64, u64, u64, u32]
    lib.core_render_frames.restype = u32
    lib.core_render_frames.argtypes = [p, u64]
    lib.core_fleet_out.restype = p
    lib.core_fleet_out.argtypes = [p, u32, ctypes.POINTER(u64)]
    lib.core_fleet_out_clear.argtypes = [p, u32]
    lib.core_drop_frames.argtypes = [p, u32, u32]
    lib.core_set_coil_rule.argtypes = [p, u32, u32, u32]
    lib.core_set_pins.argtypes = [p, u32, p]
    lib.core_power_up.argtypes = [p, u32, u64, u32, u32, p]
    lib.core_set_grammar.argtypes = [p, u32, u32, p, ctypes.c_char_p, p, p]
    lib.core_frame_receiver.argtypes = [p, i32, u32, u32, p]
    lib.core_remove_modules.restype = lib.core_remove_receiver.restype = i32
    lib.core_remove_modules.argtypes = [p, u32, u32]
    lib.core_remove_receiver.argtypes = [p, i32]
    lib.core_put_light.restype = i32
    lib.core_put_light.argtypes = [p, u64, i32, u32, p, p, u32, p, u32, u32, p, u32]
    lib.core_next.restype = u64
    lib.core_next.argtypes = [p]
    lib.core_run.restype = u64
    lib.core_run.argtypes = [p, u64]
    for name in ("core_out", "core_out_bytes", "core_out_starts", "core_out_srcs"):
        getattr(lib, name).restype = p
    lib.core_out_n.restype = u32
    lib.core_out_nbytes.restype = lib.core_out_nsrcs.restype = u32
    for name in ("core_out_n", "core_out", "core_out_bytes", "core_out_starts", "core_out_srcs",
                 "core_out_clear", "core_out_nbytes", "core_out_nsrcs", "core_flush_ports"):
        getattr(lib, name).argtypes = [p]
    return lib


def _view(addr: int, dtype: Any, n: int) -> np.ndarray:
    """The first ``n`` items of a buffer of the core. Its buffers only grow (realloc), so a
    view made once at an address serves any ``n`` up to its length while the address holds:
    making one costs more than a small window's outputs."""
    if n == 0 or not addr:
        return np.empty(0, dtype=dtype)
    key = (addr, dtype)
    v = _VIEWS.get(key)
    if v is None or len(v) < n:
        if len(_VIEWS) >= 64:
            _VIEWS.clear()
        size = np.dtype(dtype).itemsize * n
        v = _VIEWS[key] = np.frombuffer((ctypes.c_char * size).from_address(addr), dtype=dtype, count=n)
    return v[:n]


_VIEWS: dict[tuple[int, Any], np.ndarray] = {}


class _Fleet:
    """What the core knows of one fleet: its bus, its world and its modules' indexes."""

    def __init__(self, bus: Bus, world: "World", modules: list["VirtualModule"], first: int, fid: int) -> None:
        self.bus = bus
        self.fid = fid  # its rendered samples' buffer in the core (core_fleet_out)
        self.world = world
        self.modules = modules
        self.index = {m.name: first + k for k, m in enumerate(modules)}  # endpoint -> core module
        self.external_rx: dict[tuple[str, int], int] = {}  # (endpoint, transceiver) -> receiver
        self.sources: dict[str, int] = {}  # endpoint outside the core -> source id
        self.light: dict[tuple[str, int], tuple[list, np.ndarray]] = {}  # routes of outside light
        self.coil_rule = _COIL_STOP  # what the core was last told (core.c COIL_*)

    def coil_rule_now(self) -> int:
        mechanics = self.world.mechanics
        if mechanics is None:
            return _COIL_FREE
        return _COIL_MAGNETS if mechanics.at_rest() else _COIL_STOP


class FleetCore:
    """The compiled loop of the firmware-program virtual modules of every fleet on one virtual
    clock (one profile), and of their IR medium. One per clock (:meth:`of`): fleets are added
    with :meth:`add_fleet`, and one window runs them all."""

    _of_clock: "weakref.WeakKeyDictionary[Any, FleetCore]" = weakref.WeakKeyDictionary()

    @classmethod
    def of(cls, clock: Any, profile: str) -> "FleetCore | str":
        """The clock's core (made on first use), or why a fleet of ``profile`` cannot join it."""
        core = cls._of_clock.get(clock)
        if core is None:
            core = cls._of_clock[clock] = cls(clock, profile)
        if core.profile != profile:
            return (f"another fleet on this clock runs the core with profile {core.profile} "
                    "(one profile a clock)")
        return core

    def __init__(self, clock: Any, profile: str) -> None:
        self._clock = weakref.ref(clock)  # the clock keeps its core (of), not the other way
        self.profile = profile
        self.lib = lib = _library()
        # the libraries module_sim.firmware loads (the core loads a private copy of each:
        # their globals are its own), and their state at power-up as it took it before any
        # board ran
        programs = [Program.get(board, profile) for board in ("control", "comm")]
        paths = [str(build_path("lib", board, profile)).encode() for board in ("control", "comm")]
        table = (ctypes.c_int8 * 256)(*[(-1 if (k := ir_selected(v)) is None else k) for v in range(256)])
        self._h = lib.core_new(paths[0], paths[1], programs[0].power_on, programs[1].power_on,
                               ctypes.addressof(table), PORTS.index(IR_SEL_A.port),
                               bytes(COIL_MASK[p] for p in PORTS))
        if not self._h:
            raise MemoryError("the fleet core could not be made")
        lib.core_set_magnet_pins(self._h, bytes(
            v for s in range(1, 7) for pin in (MAGNET_POS[s], MAGNET_NEG[s]) for v in (PORTS.index(pin.port), pin.mask)))
        weakref.finalize(self, lib.core_free, self._h)
        error = lib.core_error(self._h)
        if error:
            raise FirmwareError(error.decode())
        self.modules: list[VirtualModule | None] = []  # by core index (None: its fleet left)
        self._fleets: dict[int, _Fleet] = {}  # id(world) -> its fleet
        self._rx: dict[int, tuple[_Fleet, str, int]] = {}  # receiver -> (fleet, endpoint, transceiver)
        self._rx_out: dict[int, tuple[Bus, str, str]] = {}  # receiver -> its bus, key and JSON part
        self._src_names: dict[int, str] = {}  # source id -> endpoint
        self._quoted: dict[str, str] = {}  # endpoint -> its JSON string
        self._timer: Any = None
        self._timer_at = _NO_TIME
        # frames: the core renders and queues them (core.c "frames"); Python frames a write it
        # was handed (a frame it does not know whole, a wire whose framer holds bytes)
        self._framed: list[tuple[int, Any, int]] = []  # its frames: (t_last, frame, first)
        self._parts: dict[tuple[str, bytes], tuple[int, bool]] = {}  # -> (core parts id, whole)
        self._fids = itertools.count()
        self._out_n = ctypes.c_uint64()
        self._batches: dict[Bus, list[tuple[str, bytes]]] = {}  # the window's samples, per bus
        self._burst = itertools.count()  # burst numbers of what goes out on ir/rx
        self.windows = 0
        self.light_taken = 0  # bursts from outside the core it took (put_light)
        self.run_ns = 0  # wall time inside core_run (the rest of a window is Python's)
        # The PC's receivers: a framer like the PC's own follows their bytes, so the core
        # stops a window only at a byte on which the PC's framer can act (core.c quiet_byte)
        pats, first = patterns(Link.CENTRE)
        width = max(map(len, pats))
        flat = (ctypes.c_int16 * (len(pats) * width))(*[b for p in pats for b in p + (-1,) * (width - len(p))])
        order = [t for c in first for t in c]
        at = list(itertools.accumulate(map(len, first), initial=0))
        lib.core_set_grammar(self._h, len(pats), width, flat, bytes(map(len, pats)),
                             (ctypes.c_int16 * max(len(order), 1))(*order), (ctypes.c_uint32 * 257)(*at))
        self._framers: dict[int, Framer] = {}  # framed receiver -> its framer

    @property
    def clock(self) -> Any:
        return self._clock()

    # -- wiring ------------------------------------------------------------------------------
    def add_fleet(self, bus: Bus, world: "World", modules: list["VirtualModule"]) -> None:
        """A fleet's world (whose geometry routes its light) and the Python shells of its
        modules in the core (their ports, framers and records)."""
        first = self.lib.core_add_modules(self._h, len(modules))
        fleet = self._fleets[id(world)] = _Fleet(bus, world, modules, first, next(self._fids))
        for k, m in enumerate(modules):
            m.core_index = first + k
            self.modules.append(m)
            for w, pub in enumerate(m._core_wires):  # what its frames are rendered from
                key = bus.keys.frame(pub.link.value, pub.src).encode()
                names0, names1 = (n.encode() for n in frame_json_names(pub.src, pub.dst, _ORIGIN, pub.channel))
                self.lib.core_set_wire(self._h, first + k, w, fleet.fid, _LINKS.index(pub.link), key, len(key),
                                       names0, len(names0), names1, len(names1))
            self._name_source(first + k, f"{m.name}.comm")
            for t in range(7):
                self._rx[self.lib.core_receiver(self._h, first + k, t)] = (fleet, m.name, t)
        world.core = self
        self.routes_changed(world)

    def remove_fleet(self, world: "World") -> None:
        """Take ``world``'s fleet out of the core: what the core made for it so far is
        published first, then its modules stop as at power-off (for good: their indexes are
        not reused; a frame whose last byte would end later never ends), its light goes
        nowhere and light still in the air to it is lost. The other fleets run on; the
        world's own medium carries its light from then on."""
        fleet = self._fleets.pop(id(world), None)
        if fleet is None:
            raise ValueError("this world's fleet is not in the core")
        self._take_outputs()
        self._publish_frames(self.clock.now_ns())
        self._flush()
        if fleet.modules:
            first, n = fleet.modules[0].core_index, len(fleet.modules)
            self.lib.core_drop_frames(self._h, first, n)
            if self.lib.core_remove_modules(self._h, first, n):
                raise FirmwareError("the fleet core refused to remove a fleet's modules")
        for r in [r for r, (f, _, _) in self._rx.items() if f is fleet]:
            if r in fleet.external_rx.values():
                self.lib.core_remove_receiver(self._h, r)
            del self._rx[r]
            self._rx_out.pop(r, None)
            self._framers.pop(r, None)
        for m in fleet.modules:
            self.modules[m.core_index] = None
            m.core_index = -1
        world.core = None

    def _receiver(self, fleet: _Fleet, dst: str, transceiver: int) -> int:
        """The core's index of a receiving transceiver (inside the core or outside)."""
        k = fleet.index.get(dst)
        if k is not None:
            return self.lib.core_receiver(self._h, k, transceiver)
        r = fleet.external_rx.get((dst, transceiver))
        if r is None:
            r = fleet.external_rx[(dst, transceiver)] = self.lib.core_add_external_receiver(self._h)
            self._rx[r] = (fleet, dst, transceiver)
            if dst == PC and transceiver == 0:  # the planner's endpoint frames the centre link
                self._framers[r] = Framer(Link.CENTRE)
                self._frame(r)
        return r

    def _frame(self, r: int) -> None:
        """Tell the core where receiver ``r``'s framer stands (after Python fed it)."""
        state = self._framers[r].waiting()
        if state is not None:
            held, alive = state
            if self.lib.core_frame_receiver(self._h, r, held, len(alive), (ctypes.c_int16 * max(len(alive), 1))(*alive)):
                raise FirmwareError(f"the fleet core refused receiver {r}'s framer state")

    def _source(self, fleet: _Fleet, src: str) -> int:
        s = fleet.sources.get(src)
        if s is None:
            s = fleet.sources[src] = self.lib.core_add_external_source(self._h)
            self._name_source(s, src)
        return s

    def _name_source(self, s: int, name: str) -> None:
        self._src_names[s] = name
        self._quoted[name] = _dumps(name)

    def routes_changed(self, world: "World", modules: list[str] | None = None) -> None:
        """Where the light of ``modules`` (default: every core module of ``world``) goes,
        from the world's geometry (after a move: the modules around its two cells)."""
        fleet = self._fleets[id(world)]
        set_route = self.lib.core_set_route
        chosen = fleet.modules if modules is None else \
            [fleet.modules[fleet.index[name] - fleet.modules[0].core_index] for name in modules
             if name in fleet.index]
        for m in chosen:
            src = f"{m.name}.comm"
            for t in range(7):
                out = world._receivers(src, t)
                set_route(self._h, m.core_index, t, self._receiver(fleet, *out[0]) if out else -1)
        fleet.light.clear()

    # -- what Python does to the core ---------------------------------------------------------
    def power_up(self, module: "VirtualModule") -> None:
        """Both boards of ``module`` power up now (FirmwareDriver.power_up, in the core)."""
        now = self.clock.now_ns()
        k = module.core_index
        if k < 0:
            raise FirmwareError(f"{module.name}'s fleet was removed from the fleet core")
        for b, mcu in ((2 * k, module.ctrl), (2 * k + 1, module.comm)):
            mcu._boot_ns = now
            pins = (ctypes.c_uint8 * 5)(*module.input_pins(mcu))
            self.lib.core_power_up(self._h, b, now, mcu.uart0.byte_ns, mcu.uart1.byte_ns, ctypes.addressof(pins))
        self._after_call()

    def set_pins(self, module: "VirtualModule") -> None:
        if module.core_index < 0:
            return  # its fleet left the core: its boards are off for good
        pins = (ctypes.c_uint8 * 5)(*module.input_pins(module.comm))
        self.lib.core_set_pins(self._h, 2 * module.core_index + 1, ctypes.addressof(pins))

    def put_light(self, world: "World", d: dict[str, Any], receivers: list[tuple[str, int]]) -> None:
        """A burst from outside the core (an ``ir/tx`` sample of ``world``'s fleet) reaches
        ``receivers``. A malformed one (:func:`bus.ir.burst_light`) raises ValueError before
        it touches the core: from another process, a ``bad-sample`` event."""
        data, starts_list, byte_ns, corrupt = burst_light(d)
        fleet = self._fleets[id(world)]
        key = (d["src"], d["transceiver"])
        cached = fleet.light.get(key)
        if cached is None or cached[0] != receivers:
            idx = np.array([self._receiver(fleet, dst, t) for dst, t in receivers], dtype=np.int32)
            cached = fleet.light[key] = (receivers, idx)
        idx = cached[1]
        if not len(idx):
            return
        starts = np.array(starts_list, dtype=np.uint64)
        flags = bytes(corrupt) if True in corrupt else None
        refused = self.lib.core_put_light(self._h, self.clock.now_ns(), self._source(fleet, d["src"]), len(idx),
                                          idx.ctypes.data, data, len(data), starts.ctypes.data, len(starts),
                                          byte_ns, flags, len(flags or b""))
        if refused:  # what burst_light checks, checked again where the bytes are read
            raise ValueError(f"the fleet core refused a burst from {d['src']}: {_LIGHT_REFUSED.get(refused, refused)}")
        self.light_taken += 1
        self._after_call()

    def queue_frame(self, bus: Bus, t_last: int, frame: Any, src: str, dst: str, first: int,
                    channel: int | None) -> None:
        """A frame Python framed from the write it is framing: the core publishes it once the
        run reaches ``t_last``."""
        self._framed.append((t_last, frame, first))

    def _frame_write(self, m: int, wire: int, ordinal: int, data: bytes, starts: list[int], byte_ns: int) -> None:
        """Frame a write the core handed over, queue its frames in the core, and tell the core
        what it may render alone from now on: a write of these bytes on this link, whole,
        from an empty framer (the framer's own cache of whole writes, taught to the core)."""
        pub = self.modules[m]._core_wires[wire]  # type: ignore[union-attr]
        framer = pub.framer
        was_empty = framer.idle
        self._framed.clear()
        pub(data, starts, byte_ns)
        empty = framer.idle
        framed = self._framed
        whole = was_empty and empty and len(framed) == 1 and framed[0][1].raw == data
        lib, h = self.lib, self._h
        for t_last, frame, first in framed:
            lib.core_queue_frame(h, m, wire, t_last, ordinal, first, self._parts_of(frame, whole))
        if empty:
            lib.core_wire_empty(h, m, wire, 1)

    def _parts_of(self, frame: Any, whole: bool) -> int:
        """The core's id of ``frame``'s envelope parts (bus.transport.frame_json_parts), made
        once per link and bytes (a noise frame's view says what came around it: each its own)."""
        kind = frame.kind.value
        key = (frame.link.value, frame.raw)
        known = self._parts.get(key) if kind != "noise" else None
        if known is not None and (known[1] or not whole):
            return known[0]
        keep = kind != "noise" and (known is not None or len(self._parts) < _PARTS_MAX)
        p0, p1, p2 = (x.encode() for x in frame_json_parts(frame.link.value, frame.raw, kind, frame.view))
        raw = frame.raw
        pid = self.lib.core_add_parts(self._h, _LINKS.index(frame.link), raw, len(raw),
                                      (_PARTS_WHOLE if whole else _PARTS_KEPT) if keep else _PARTS_ONCE,
                                      p0, len(p0), p1, len(p1), p2, len(p2))
        if keep:
            self._parts[key] = (pid, whole)
        return pid

    def put(self, bus: Bus, key: str, payload: bytes) -> None:
        """A sample of the window, put with the others at its end (:meth:`Bus.put_batch`)."""
        batch = self._batches.get(bus)
        if batch is None:
            batch = self._batches[bus] = []
        batch.append((key, payload))

    # -- windows ----------------------------------------------------------------------------
    def _after_call(self) -> None:
        self._take_outputs()
        self._flush()
        self._kick()

    def _kick(self) -> None:
        """Book the next window at the core's next event (or the next frame due)."""
        nxt = self.lib.core_next(self._h)  # its next event, or the next frame's last byte
        if nxt >= self._timer_at:
            return
        if self._timer is not None:
            self._timer.cancel()
        self._timer_at = nxt
        self._timer = self.clock.call_at(nxt, self._window)

    def _window(self) -> None:
        self._timer, self._timer_at = None, _NO_TIME
        clock = self.clock
        now = clock.now_ns()
        limit = now + MAX_WINDOW_NS
        nxt = clock.next_due_ns()
        if nxt is not None and nxt < limit:
            limit = nxt
        if clock.inbox_waiting():  # samples of this instant (light for the core?) come in first
            limit = now + 1
        if clock.until_ns is not None and clock.until_ns + 1 < limit:
            limit = clock.until_ns + 1
        for fleet in self._fleets.values():  # judged now: Python acted since the last window
            rule = fleet.coil_rule_now()
            if rule != fleet.coil_rule and fleet.modules:
                self.lib.core_set_coil_rule(self._h, fleet.modules[0].core_index, len(fleet.modules), rule)
                fleet.coil_rule = rule
        t0 = perf_counter_ns()
        reached = self.lib.core_run(self._h, max(limit, now + 1))
        self.run_ns += perf_counter_ns() - t0
        self.windows += 1
        if reached > now:
            clock.advance_to(reached)
        self._take_outputs()
        self._publish_frames(clock.now_ns())
        self._flush()
        self._kick()

    def _publish_frames(self, now: int) -> None:
        """The core renders every frame whose last byte ended by ``now`` (after the window's
        other samples, in the order of their last bytes: each source's ``seq`` in that order)."""
        self.lib.core_render_frames(self._h, now)

    def _flush(self) -> None:
        lib, h, n = self.lib, self._h, self._out_n
        batches, self._batches = self._batches, {}
        for fleet in self._fleets.values():
            addr = lib.core_fleet_out(h, fleet.fid, ctypes.byref(n))
            items = batches.pop(fleet.bus, None)
            if n.value:
                frames = ctypes.string_at(addr, n.value)
                lib.core_fleet_out_clear(h, fleet.fid)
                fleet.bus.put_packed(pack_batch(items) + frames if items else frames)
            elif items:
                fleet.bus.put_batch(items)
        for bus, items in batches.items():  # a fleet that left the core in this window
            bus.put_batch(items)

    def _take_outputs(self) -> None:
        lib, h = self.lib, self._h
        lib.core_flush_ports(h)  # what power-up or light from outside wrote now
        n = lib.core_out_n(h)
        error = lib.core_error(h)
        if error:
            raise FirmwareError(error.decode())
        if not n:
            return
        out = _view(lib.core_out(h), _OUT, n).tolist()
        nbytes = lib.core_out_nbytes(h)
        raw = ctypes.string_at(lib.core_out_bytes(h), nbytes) if nbytes else b""
        starts = _view(lib.core_out_starts(h), np.uint64, nbytes)
        srcs = None
        modules = self.modules
        rx_out, quoted, src_names, framers = self._rx_out, self._quoted, self._src_names, self._framers
        framed_now: dict[int, tuple[bytearray, list[int]]] = {}  # framed receiver -> its bytes, their ends
        for t, aux, kind, m, a, b, cnt, off, off2, n2 in out:
            if kind == _OUT_TX:  # aux: the write's ordinal (frames of one instant keep its order)
                self._frame_write(m, a, aux, raw[off:off + cnt], starts[off:off + cnt].tolist(), b)
            elif kind == _OUT_PORTS:  # one record per module and instant
                module = modules[m]
                module.core_ports(raw[off:off + 10])
                module.publish_actuators(t)
            elif kind == _OUT_RX:
                held = framed_now.get(m)
                if held is not None:
                    held[0].append(a)
                    held[1].append(t)
                elif m in framers:
                    framed_now[m] = (bytearray([a]), [t])
                to = rx_out.get(m)
                if to is None:
                    fleet, dst, rx = self._rx[m]
                    to = rx_out[m] = (fleet.bus, fleet.bus.keys.ir_rx(dst), burst_tail(dst, rx))
                self.put(to[0], to[1], one_byte_burst(quoted[src_names[cnt]], next(self._burst), a, aux,
                                                      t - aux, to[2], bool(b)))
            elif kind == _OUT_OVERRUN:
                # n: the transceiver of an IR byte (-1: none), -2: not the IR UART
                modules[m // 2].core_overrun(t, m & 1, a, b,
                                             {} if cnt == -2 else {"channel": None if cnt < 0 else cnt})
            elif kind == _OUT_COLLISION:
                if srcs is None:
                    srcs = _view(lib.core_out_srcs(h), np.int32, lib.core_out_nsrcs(h)).tolist()
                # bus.event's JSON, the sources' names encoded once each
                names = ",".join(map(self._quoted.__getitem__,
                                     sorted(map(self._src_names.__getitem__, srcs[off:off + cnt]))))
                fleet, dst, rx = self._rx[m]
                fleet.world.collisions += 1
                self.put(fleet.bus, fleet.bus.keys.event(WORLD), (
                    f'{{"kind":"collision","src":"{WORLD}","sim_time_ns":{t},"receiver":{_dumps(dst)},'
                    f'"transceiver":{rx},"sources":[{names}],"received":"{raw[off2:off2 + n2].hex()}"}}').encode())
        lib.core_out_clear(h)
        for r, (data, ends) in framed_now.items():  # in one chunk: the framer's cache knows most
            framers[r].feed(data, ends)
            self._frame(r)


_dumps = json.JSONEncoder(separators=(",", ":")).encode

__all__ = ["FleetCore", "MAX_WINDOW_NS"]

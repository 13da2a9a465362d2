"""hexbench's pytest plugin (entry point ``pytest11``): wire-protocol tests against any target.

Options:

* ``--hexbench-target virtual`` (default): a virtual module on a private bus, virtual clock.
* ``--hexbench-target serial:<url>``: a module already powered up behind a serial port (any
  pyserial URL: ``/dev/ttyUSB0``, ``socket://host:port``, a pty of ``hexbench standin``), reached
  through a :class:`hil.bridge.CentreBridge` on a private bus with the wall clock. Give the
  board's firmware with ``--hexbench-profile v2`` or ``thesis-2009``.
* ``--hexbench-target firmware``: as ``virtual``, but the module runs the C firmware compiled
  for the host (:mod:`module_sim.firmware`) instead of the Python programs.
* ``--hexbench-target simavr``: the C firmware of ``firmware/`` in simavr (our ATmega162
  core), one fresh module per test, reached like a serial target through its IR pty
  (:class:`hil.firmware.FirmwareModule`); the module powers up when the test starts, so the
  boot banners are observable. Builds the firmware first if needed (avr-gcc, libsimavr).
* ``--hexbench-profile v2|thesis-2009|both`` (default both; a serial target needs one).
* ``--hexbench-baud N``: IR baud rate of the target (default 300).

Fixtures, all named ``hexbench_*`` so that they cannot shadow a user's own: ``hexbench_bench``
(a single-module bench: ``.pc``, ``.clock``, ``.module`` for virtual targets), ``hexbench_pc``
(the bench's PC endpoint, after the module finished booting), ``hexbench_target`` and
``hexbench_profile``. The conformance suite for spec §5-§9 ships in ``hexbench.conformance``:
``pytest --pyargs hexbench.conformance --hexbench-target virtual``.

Serial targets: everything observable on the centre channel runs (ACK bytes, ``N`` for unknown
codes, garbage resilience, ...). What is not observable on real hardware skips with the reason:
the boot banners (the module booted before the port was opened: no power cycle), port bits and
halting a board (``bench.module``; a test that checked ACKs before asking for the module has run
those checks), UART0. Waits are timeouts in wall seconds; the suite's timeouts are several times
the wire time of what they wait for. A test that compares times should allow
``bench.time_tolerance_ns`` (0 on the virtual clock; on the wall clock two byte times plus
scheduling latency, since bytes are timestamped on arrival at the PC).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Iterator

import pytest

_fleets = itertools.count()


def pytest_addoption(parser) -> None:
    group = parser.getgroup("hexbench")
    group.addoption("--hexbench-target", default="virtual",
                    help="what the conformance suite talks to: 'virtual' (default), 'firmware' "
                         "(the C firmware as the virtual module's program), 'simavr' (the C "
                         "firmware in simavr) or 'serial:<url>'")
    group.addoption("--hexbench-profile", default="both", choices=["v2", "thesis-2009", "both"],
                    help="firmware profile of the target (default: both, for virtual targets; "
                         "a serial target needs the board's profile)")
    group.addoption("--hexbench-baud", type=int, default=300,
                    help="IR baud rate of the target (default 300)")


def pytest_configure(config) -> None:
    target = config.getoption("--hexbench-target", "virtual")
    if target in ("virtual", "firmware", "simavr"):
        return
    if not target.startswith("serial:") or not target[len("serial:"):]:
        raise pytest.UsageError(f"--hexbench-target {target!r}: expected 'virtual', 'firmware', 'simavr' or "
                                "'serial:<url>' (e.g. serial:/dev/ttyUSB0, serial:socket://host:7000)")
    if config.getoption("--hexbench-profile") == "both":
        raise pytest.UsageError(f"--hexbench-target {target}: give the board's firmware with "
                                "--hexbench-profile v2 or --hexbench-profile thesis-2009")


def pytest_generate_tests(metafunc) -> None:
    if "hexbench_profile" in metafunc.fixturenames:
        opt = metafunc.config.getoption("--hexbench-profile")
        metafunc.parametrize("hexbench_profile", ["v2", "thesis-2009"] if opt == "both" else [opt])


@pytest.fixture
def hexbench_target(request) -> str:
    return request.config.getoption("--hexbench-target")


@dataclass
class Bench:
    """One module under test and the PC that talks to it."""

    target: str
    profile: str
    clock: object
    bus: object
    pc: object
    fleet: object | None = None
    module_id: int = 1
    booted: bool = False
    boot_frames: list = field(default_factory=list)
    bridge: object | None = None  # serial targets: the hil.bridge.CentreBridge

    @property
    def virtual(self) -> bool:
        """A virtual fleet on the virtual clock (the Python programs or the C firmware)."""
        return self.target in ("virtual", "firmware")

    @property
    def fresh(self) -> bool:
        """The module powered up for this test (virtual or simavr): its boot is observable
        and what a test does to it cannot leak into the next test."""
        return self.target in ("virtual", "firmware", "simavr")

    @property
    def time_tolerance_ns(self) -> int:
        """How far a measured time may stray from the program's: exact on the virtual clock."""
        return 0 if self.virtual else 2 * self.pc.byte_ns + 20_000_000

    @property
    def module(self):
        if not self.virtual:
            pytest.skip(f"port bits and board internals are not observable on {self.target} "
                        "(centre-channel checks before this point ran and passed)")
        return self.fleet.modules[self.module_id]

    def boot(self, timeout_s: float = 30.0):
        """Wait for the boot sequence to finish (the ``COMM. LISTENING`` banner)."""
        if not self.fresh:
            pytest.skip(f"the boot banners need a power cycle: the module on {self.target} booted "
                        "before the port was opened")
        if not self.booted:
            self.pc.expect("banner", banner="COMM_LST", timeout_s=timeout_s, since=0)
            self.boot_frames = list(self.pc.received)
            self.booted = True
        return self.boot_frames


@pytest.fixture
def hexbench_bench(request, hexbench_target: str, hexbench_profile: str) -> Iterator[Bench]:
    from bus.clock import VirtualClock
    from bus.scenario import loads
    from bus.session import SessionOptions
    from bus.transport import Bus
    from planner_svc.endpoint import PcEndpoint

    from module_sim.fleet import Fleet

    baud = request.config.getoption("--hexbench-baud")
    if hexbench_target == "simavr":
        yield from _simavr_bench(hexbench_profile, baud)
        return
    if hexbench_target not in ("virtual", "firmware"):
        yield from _serial_bench(hexbench_target, hexbench_profile, baud)
        return
    clock = VirtualClock()
    bus = Bus(clock, f"conformance{next(_fleets)}", options=SessionOptions(isolated=True))
    try:
        program = "firmware" if hexbench_target == "firmware" else "model"
        scenario = loads(f'profile = "{hexbench_profile}"\nir_baud = {baud}\nprogram = "{program}"\n'
                         '[[modules]]\ncell = [0, 0]\nid = 1\n')
        fleet = Fleet(bus, scenario)
        pc = PcEndpoint(bus, baud=baud)
        fleet.power_up(stagger=False)
        yield Bench(hexbench_target, hexbench_profile, clock, bus, pc, fleet)
    finally:
        bus.close()


def _simavr_bench(profile: str, baud: int) -> Iterator[Bench]:
    """A fresh firmware module in simavr, held until the bridge has opened its IR pty."""
    from hil.firmware import FirmwareError, FirmwareModule

    try:
        fw = FirmwareModule(1, profile, hold=True).start()
    except FirmwareError as exc:
        pytest.fail(f"target simavr: {exc}", pytrace=False)
    try:
        yield from _serial_bench(f"serial:{fw.ir_path}", profile, baud, simavr=True)
    finally:
        fw.close()


def _serial_bench(target: str, profile: str, baud: int, *, simavr: bool = False
                  ) -> Iterator[Bench]:
    """A PC endpoint whose transceiver is a serial port: bridge, bus and PC on the wall clock."""
    import serial

    from bus.clock import WallClock
    from bus.session import SessionOptions
    from bus.transport import Bus
    from hil.bridge import CentreBridge
    from planner_svc.endpoint import PcEndpoint

    url = target[len("serial:"):]
    clock = WallClock()
    bus = Bus(clock, f"conformance{next(_fleets)}", options=SessionOptions(isolated=True))
    bridge = None
    try:
        try:
            bridge = CentreBridge(bus, url, baud=baud).start()
        except (serial.SerialException, ValueError) as exc:
            pytest.fail(f"target {target}: {exc}", pytrace=False)
        pc = PcEndpoint(bus, baud=baud)
        if simavr:  # the harness starts simulating once the bridge has opened the pty
            bench = Bench("simavr", profile, clock, bus, pc, bridge=bridge)
        else:
            bench = Bench(target, profile, clock, bus, pc, bridge=bridge, booted=True)
            _quiet(bench)
        yield bench
    finally:
        if bridge is not None:
            bridge.close()
        bus.close()


def _quiet(bench: Bench, *, quiet_bytes: int = 4, timeout_s: float = 10.0) -> None:
    """Start from a quiet line: run until nothing arrived for a few byte times (a line the
    module was still sending when the port opened is over)."""
    clock, pc = bench.clock, bench.pc
    quiet_ns = quiet_bytes * pc.byte_ns
    deadline = clock.now_ns() + int(timeout_s * 1e9)
    last = [clock.now_ns(), bench.bridge.port.bytes_in]

    def quiet() -> bool:
        now = clock.now_ns()
        if bench.bridge.port.bytes_in != last[1]:
            last[:] = [now, bench.bridge.port.bytes_in]
        return now - last[0] >= quiet_ns

    clock.run(until=quiet, until_ns=deadline)
    pc.flush()
    pc.received.clear()


@pytest.fixture
def hexbench_pc(hexbench_bench: Bench):
    if hexbench_bench.fresh:
        hexbench_bench.boot()
    return hexbench_bench.pc

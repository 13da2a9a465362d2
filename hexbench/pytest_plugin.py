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
* ``--hexbench-debug serial:<url>``: with a serial target, the module's debug UART1 (4800 baud):
  a v2 board's actuator reports (``ACT``) then show what each test left energised.

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

After each test that sent anything, the bench switches every actuator off: ``TurnOffAll`` (20)
and ``LOff`` (45), each sent again (after the line went quiet) until its ACK comes back, so a
module still busy with the test's last command is caught once it listens again. A module that
outlives the test (a serial target) and never acknowledges is a teardown error. With
``--hexbench-debug`` the last actuator report the board sent is each test's user property
``hexbench_actuators`` (JSON, ``null`` before any; ``hexbench_actuator_reports``: how many came
during the test, in ``--junitxml``), and one that still shows an actuator on after the
switch-off is a teardown error.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from typing import Iterator

import pytest

_fleets = itertools.count()
#: Each debug port's last actuator report, across the tests of a session.
_LAST_ACT = pytest.StashKey[dict]()


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
    group.addoption("--hexbench-debug", metavar="serial:<url>",
                    help="with a serial target: the module's debug UART1 (4800 baud), whose actuator "
                         "reports show what each test left on")


def pytest_configure(config) -> None:
    target = config.getoption("--hexbench-target", "virtual")
    debug = config.getoption("--hexbench-debug", None)
    if debug is not None and (not target.startswith("serial:") or not debug.startswith("serial:")
                              or not debug[len("serial:"):]):
        raise pytest.UsageError(f"--hexbench-debug {debug!r}: expected 'serial:<url>' (the module's debug "
                                "UART1), with a --hexbench-target serial:<url>")
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
    debug: object | None = None  # --hexbench-debug: the hil.bridge.DebugBridge
    debug_frames: list = field(default_factory=list)  # what it framed during the test

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
    baud = request.config.getoption("--hexbench-baud")
    if hexbench_target == "simavr":
        benches = _simavr_bench(hexbench_profile, baud)
    elif hexbench_target in ("virtual", "firmware"):
        benches = _virtual_bench(hexbench_target, hexbench_profile, baud)
    else:
        benches = _serial_bench(hexbench_target, hexbench_profile, baud,
                                debug=request.config.getoption("--hexbench-debug"))
    bench = next(benches)
    try:
        yield bench
        try:
            switch_off(bench)
        finally:
            if bench.debug is not None:
                _note_actuators(request, bench)
    finally:
        benches.close()


def _virtual_bench(target: str, profile: str, baud: int) -> Iterator[Bench]:
    """One virtual module (the Python programs, or the C firmware) on a private virtual-clock bus."""
    from bus.clock import VirtualClock
    from bus.scenario import loads
    from bus.session import SessionOptions
    from bus.transport import Bus
    from planner_svc.endpoint import PcEndpoint

    from module_sim.fleet import Fleet

    clock = VirtualClock()
    bus = Bus(clock, f"conformance{next(_fleets)}", options=SessionOptions(isolated=True))
    try:
        program = "firmware" if target == "firmware" else "model"
        scenario = loads(f'profile = "{profile}"\nir_baud = {baud}\nprogram = "{program}"\n'
                         '[[modules]]\ncell = [0, 0]\nid = 1\n')
        # the suite watches every port write as it happens (Mcu hooks, time series): the
        # firmware's own driver gives them; the fleet core hands over ports per instant
        fleet = Fleet(bus, scenario, core=False)
        pc = PcEndpoint(bus, baud=baud)
        fleet.power_up(stagger=False)
        yield Bench(target, profile, clock, bus, pc, fleet)
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


def _serial_bench(target: str, profile: str, baud: int, *, simavr: bool = False,
                  debug: str | None = None) -> Iterator[Bench]:
    """A PC endpoint whose transceiver is a serial port: bridge, bus and PC on the wall clock;
    with ``debug`` (``serial:<url>``) the module's debug UART1 bridged on the same bus."""
    import serial

    from hil.bridge import DebugBridge

    from .serial_pc import SerialPc

    try:
        spc = SerialPc(target[len("serial:"):], baud=baud, name="conformance")
    except (serial.SerialException, ValueError) as exc:
        pytest.fail(f"target {target}: {exc}", pytrace=False)
    bench = None
    try:
        if simavr:  # the harness starts simulating once the bridge has opened the pty
            bench = Bench("simavr", profile, spc.clock, spc.bus, spc.pc, bridge=spc.bridge)
        else:
            bench = Bench(target, profile, spc.clock, spc.bus, spc.pc, bridge=spc.bridge, booted=True)
        if debug is not None:
            spc.bus.subscribe_frames(bench.debug_frames.append, "debug")
            try:
                bench.debug = DebugBridge(spc.bus, debug[len("serial:"):], bench.module_id).start()
            except (serial.SerialException, ValueError) as exc:
                pytest.fail(f"--hexbench-debug {debug}: {exc}", pytrace=False)
        if not simavr:
            spc.quiet()  # start from a quiet line: what the module was still sending is over
            spc.pc.received.clear()
        yield bench
    finally:
        if bench is not None and bench.debug is not None:
            bench.debug.close()
        spc.close()


#: What each test leaves behind: every solenoid and magnet off, then every LED.
SWITCH_OFF = ("TurnOffAll", "LOff")


def switch_off(bench: Bench, *, attempts: int = 3, timeout_s: float = 5.0) -> None:
    """After a test that sent anything, ``TurnOffAll`` and ``LOff``, each until its ACK.

    A module may still be busy with the test's last command (a rotation's steps, LED mirror):
    its comm board is not listening, or its control board echoes too late (``'~'``), and the
    frame is lost. So each is sent again, after the line went quiet, up to ``attempts`` times.
    A module that outlives the test (a serial target) and never acknowledges is a teardown
    error; a fresh one (a halted control board, say) is dropped anyway."""
    from bus.codec import encode_command
    from bus.functions import FunctionCode

    from .serial_pc import ask

    pc = bench.pc
    if pc.line_free_at == 0:  # the PC sent nothing: nothing changed since the last switch-off
        return
    for name in SWITCH_OFF:
        code, heard = FunctionCode[name], []
        for _ in range(attempts):
            _settle(bench)
            got, ack = ask(pc, encode_command(code), timeout_s=timeout_s)
            heard += [r.frame.describe() for r in got]
            if ack is not None and ack.frame.view["byte"] == code:
                break
        else:
            if not bench.fresh:
                pytest.fail(f"switching the module on {bench.target} off after the test: no ACK "
                            f"{int(code)} to {name} in {attempts} attempts (heard: {heard or 'nothing'}); "
                            "its actuators may still be on", pytrace=False)
            return


def _settle(bench: Bench, *, timeout_s: float = 10.0) -> None:
    """Run until the line to the PC is quiet for four byte times (bytes on a serial target,
    frames on a virtual one)."""
    from .serial_pc import run_until_quiet

    port = bench.bridge.port if bench.bridge is not None else None
    run_until_quiet(bench.pc, (lambda: port.bytes_in) if port else (lambda: len(bench.pc.received)),
                    timeout_s=timeout_s)


def _note_actuators(request, bench: Bench) -> None:
    """The board's last actuator report (``--hexbench-debug``) as the test's user properties;
    one that shows an actuator still on is a teardown error."""
    from .serial_pc import run_until_quiet

    debug = bench.debug
    if bench.pc.line_free_at:  # the last reports may still be on their way
        run_until_quiet(bench.pc, lambda: debug.port.bytes_in, quiet_bytes=2, timeout_s=2.0)
    reports = [{k: env.view[k] for k in ("joints_open", "magnets")}
               for env in bench.debug_frames if env.kind == "actuators"]
    last = request.config.stash.setdefault(_LAST_ACT, {})
    if reports:
        last[debug.url] = reports[-1]
    now = last.get(debug.url)
    request.node.user_properties += [("hexbench_actuator_reports", len(reports)),
                                     ("hexbench_actuators", json.dumps(now))]
    if now is not None and (any(now["joints_open"]) or any(now["magnets"])):
        pytest.fail(f"after the switch-off the board on {bench.target} still reports actuators on "
                    f"(debug UART1 {debug.url}): {now}", pytrace=False)


@pytest.fixture
def hexbench_pc(hexbench_bench: Bench):
    if hexbench_bench.fresh:
        hexbench_bench.boot()
    return hexbench_bench.pc

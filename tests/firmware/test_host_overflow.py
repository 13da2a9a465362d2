"""The host board layer's buffers (firmware/host/hexbot_host.h: HEXBOT_MAX_EVENTS events,
HEXBOT_MAX_BYTES bytes a step) never lose an event: a step that makes more hands them to the
simulator on the way (hexbot_flush). A flooding program, built here with the same board layer
as the firmware's host libraries, makes 600 port writes and 1 500 bytes in one step."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import pytest

from bus.cheader import FirmwareError
from bus.clock import VirtualClock
from module_sim.avr import Mcu, Uart
from module_sim.firmware import FirmwareDriver, Program
from toolchain import needs_tools

pytestmark = needs_tools("cc", "objcopy")

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
PORT_WRITES, BURSTS, BURST = 600, 6, 250  # > 256 events, > 1024 bytes

FLOOD = f"""
#include "hexbot.h"
const uint8_t program_outputs[5] = {{0xff, 0, 0, 0, 0}};
const uint8_t program_pullups[5] = {{0, 0, 0, 0, 0}};
static uint8_t done, data[{BURST}];

void program_step(void)
{{
    if (done)
        return;
    done = 1;
    for (uint16_t k = 0; k < {PORT_WRITES}; k++)
        board_port_write(PORT_A, (uint8_t)(k % 255 + 1)); /* each a change */
    for (uint8_t b = 0; b < {BURSTS}; b++) {{
        for (uint16_t k = 0; k < {BURST}; k++)
            data[k] = (uint8_t)(b * 7 + k);
        board_tx_queue(UART1, data, {BURST});
    }}
}}
"""


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """The flooding program as a host library, built as the Makefile builds the firmware's."""
    d = tmp_path_factory.mktemp("flood")
    (d / "flood.c").write_text(FLOOD)
    flags = ["-O2", "-fPIC", "-std=gnu99", "-Wall", "-Werror", "-fno-data-sections", "-fno-common",
             f"-I{FIRMWARE / 'include'}", f"-I{FIRMWARE / 'host'}"]
    for cmd in (["cc", *flags, "-c", "-o", "prog.o", "flood.c"],
                ["cc", *flags, "-c", "-o", "board.o", str(FIRMWARE / "host" / "board_host.c")],
                ["ld", "-r", "-o", "flood.o", "prog.o", "board.o"],
                ["objcopy", "--rename-section", ".data=.hexbot_data", "--rename-section",
                 ".bss=.hexbot_bss", "flood.o"],
                ["cc", *flags, "-shared", "-o", "libflood.so", "flood.o", str(FIRMWARE / "host" / "io.c"),
                 f"-Wl,-T,{FIRMWARE / 'host' / 'state.ld'}"]):
        subprocess.run(cmd, cwd=d, check=True, capture_output=True)
    return d / "libflood.so"


@pytest.fixture
def flood(built, tmp_path) -> Path:
    """A copy of its own: a library loaded again keeps the memory of its last step."""
    return Path(shutil.copy(built, tmp_path / "libflood.so"))


def _board(program: Program) -> tuple[FirmwareDriver, list[int], list[tuple[bytes, list[int]]]]:
    mcu = Mcu(VirtualClock(), "m9.comm")
    mcu.uart0, mcu.uart1 = Uart(mcu, "uart0", 4800), Uart(mcu, "uart1", 300)
    ports: list[int] = []
    mcu.on_ports = lambda m: ports.append(m.port["A"])
    sent: list[tuple[bytes, list[int]]] = []
    mcu.uart1.on_tx = lambda data, starts: sent.append((data, list(starts)))
    return FirmwareDriver(mcu, program), ports, sent


def test_a_step_that_fills_the_buffers_loses_nothing(flood):
    driver, ports, sent = _board(Program("comm", "v2", path=flood))
    driver.power_up()  # the one step that floods
    assert ports == [k % 255 + 1 for k in range(PORT_WRITES)]  # every write, in order
    assert [data for data, _ in sent] == [bytes((b * 7 + k) & 0xFF for k in range(BURST))
                                          for b in range(BURSTS)]
    starts = [s for _, ss in sent for s in ss]
    byte_ns = driver.mcu.uart1.byte_ns
    assert starts == [k * byte_ns for k in range(BURSTS * BURST)]  # back to back on the line


def test_with_nobody_to_take_them_the_lost_events_are_counted_and_said(flood):
    program = Program("comm", "v2", path=flood)
    ctypes.c_void_p.in_dll(program.lib, "hexbot_flush").value = None  # a harness without the hook
    driver, ports, _ = _board(program)
    with pytest.raises(FirmwareError, match=r"m9.comm: the firmware's step made more events than "
                                            r"the host board layer holds; \d+ lost"):
        driver.power_up()
    assert 0 < program.io.overflow and len(ports) <= 256

"""One truth for C and Python: the firmware's constants are bus/'s (bus.cheader)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bus import cheader, functions, pins, timing

ROOT = Path(__file__).resolve().parents[2]
HEADER = ROOT / "firmware" / "include" / "hexbot_gen.h"


def test_committed_header_matches_bus() -> None:
    r = subprocess.run([sys.executable, "-m", "bus.cheader", "--check", str(HEADER)],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr


def test_a_changed_constant_is_drift(monkeypatch, tmp_path) -> None:
    """The check has teeth: a function code, a pin or a timing constant that moves in bus/
    makes the committed header stale."""
    text = HEADER.read_text()
    assert cheader.header() == text
    monkeypatch.setattr(timing, "ECHO_TIMEOUT_TICKS", 251)
    assert "#define ECHO_TIMEOUT_TICKS 251" in cheader.header()
    monkeypatch.undo()
    monkeypatch.setitem(pins.JOINT, 1, pins.Pin.parse("PA7"))
    assert cheader.header() != text
    monkeypatch.undo()
    mcw = functions.FUNCTIONS[21]
    monkeypatch.setitem(functions.FUNCTIONS, 21, functions.Function(
        27, mcw.name, mcw.board, mcw.args, mcw.led_mirror, mcw.ack))
    assert "#define FC_MCW 27" in cheader.header()
    stale = tmp_path / "stale.h"
    stale.write_text(text.replace("#define FC_MCW 21", "#define FC_MCW 22"))
    r = subprocess.run([sys.executable, "-m", "bus.cheader", "--check", str(stale)],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 1 and "differs from bus/" in r.stderr


def test_header_values_are_the_spec() -> None:
    text = HEADER.read_text()
    for line in ("#define UART0_UBRR 12", "#define IR_UBRR 207", "#define TIMER0_TOP 155",
                 "#define FC_CW 67", "#define IR_SEL_BITS {0x02,"):
        assert line in text
    # 156 counts of 64 us: the 9.984 ms tick of bus.timing
    assert (cheader.TIMER0_TOP + 1) * cheader.TIMER0_PRESCALER * 1000 == timing.TICK_NS


def test_c_sources_take_codes_from_the_header() -> None:
    """No C file spells a function code or a pin as a number of its own."""
    import re
    for src in (ROOT / "firmware" / "src").glob("*.c"):
        body = src.read_text()
        assert not re.search(r"#define\s+(FC_|JOINT|MAGNET|LED_|IR_SEL|TICK)", body), src
        assert not re.search(r"case\s+\d+\s*:", body), f"{src}: a code as a bare number"

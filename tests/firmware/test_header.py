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
    monkeypatch.setattr(timing, "BOOT_FLASH_TICKS", 11)
    assert "#define BOOT_FLASH_TICKS 11" in cheader.header()
    monkeypatch.setattr(timing, "LOCALIZE_SLOT_GUARD_TICKS", 4)
    assert "#define LOCALIZE_SLOT_TICKS 55" in cheader.header()
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


# -- the programs' timings: named in bus.timing, used by name in both programs ---------------
MODEL = [ROOT / "module_sim" / n for n in ("comm_board.py", "control_board.py", "framing.py")]
#: The model's calls whose arguments are waits or show lengths.
MODEL_TIMED = {"Delay", "Rx", "LFlash1", "LFlash2", "LColor", "LCircle", "JTest", "SPTest", "SNTest",
               "SidePTest", "SideNTest", "JointTest"}


def _strip_c_comments(text: str) -> str:
    import re
    return re.sub(r"/\*.*?\*/|//[^\n]*", lambda m: "\n" * m.group().count("\n"), text, flags=re.S)


def _c_calls(text: str, name_pattern: str):
    """(name, argument text, line) of every call whose name matches, arguments balanced."""
    import re
    for m in re.finditer(rf"\b({name_pattern})\s*\(", text):
        depth, i = 1, m.end()
        while depth:
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            i += 1
        yield m.group(1), text[m.end():i - 1], text.count("\n", 0, m.start()) + 1


def bare_timings_c(text: str) -> list[str]:
    """Waits (DELAY, RX_TL, RX_TL2) and coroutine calls (co_*) that spell a number: a wait
    or a show length belongs in bus/timing.py. Subscripts (a[1]) are not timings."""
    import re
    found = []
    for name, args, line in _c_calls(_strip_c_comments(text), r"DELAY|RX_TL2?|co_\w+"):
        while re.search(r"\[[^\[\]]*\]", args):
            args = re.sub(r"\[[^\[\]]*\]", "", args)
        if re.search(r"(?<![\w.])(0[xX][0-9a-fA-F]+|\d+)[uUlL]*\b", args):
            found.append(f"line {line}: {name}({args})")
    return found


def bare_timings_model(text: str) -> list[str]:
    """The model's waits and shows with a number as an argument."""
    import ast
    found = []
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        if name in MODEL_TIMED and any(isinstance(a, ast.Constant) and isinstance(a.value, int)
                                       and not isinstance(a.value, bool) for a in node.args):
            found.append(f"line {node.lineno}: {ast.unparse(node)}")
    return found


def test_no_bare_timing_in_either_program() -> None:
    for src in sorted((ROOT / "firmware" / "src").glob("*.c")):
        assert bare_timings_c(src.read_text()) == [], f"{src}: name the timing in bus/timing.py"
    for src in MODEL:
        assert bare_timings_model(src.read_text()) == [], f"{src}: use bus.timing's names"


def test_a_bare_timing_is_found() -> None:
    """The check has teeth: the old spellings are caught, named ones and subscripts are not."""
    assert bare_timings_c("DELAY(pt, 10);") and bare_timings_c("PT_CALL(pt, co_circle(1, 5));")
    assert bare_timings_c("RX_TL(pt, UART1, 150, b);")
    assert bare_timings_c("PT_CALL(pt, co_flash(FC_LFlash1, 3, BOOT_FLASH_TICKS));")
    assert not bare_timings_c("DELAY(pt, t[fw_byte(&steps[s + 1]) - 1]); /* DELAY(pt, 10) */")
    assert not bare_timings_c("PT_CALL(pt, co_flash(FC_LFlash1, BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS));")
    assert not bare_timings_c("RX_TL(pt, UART1, LOCALIZE_BYTE_TICKS, body[1]);")
    comm = (ROOT / "firmware" / "src" / "comm.c").read_text()
    assert bare_timings_c(comm.replace("DELAY(pt, YREF_FLASH_TICKS)", "DELAY(pt, 10)"))
    assert bare_timings_model("yield Delay(2)") and bare_timings_model("yield from self.LCircle(1, 5)")
    assert bare_timings_model("b = yield Rx(u1, 150)")
    assert not bare_timings_model("yield Delay(t)\nyield from self.LYref(0)\nx = yield Rx(u1)")


def test_every_program_timing_is_in_the_header_and_both_programs() -> None:
    """Each wait the programs share is generated (no C file defines one of its own) and used
    by name in the C firmware and in the model."""
    import re
    text = HEADER.read_text()
    c_text = "".join(p.read_text() for p in (ROOT / "firmware" / "src").glob("*.c"))
    model_text = "".join(p.read_text() for p in MODEL)
    for name in cheader.PROGRAM_TIMING:
        assert f"#define {name} {getattr(timing, name)}\n" in text, name
        assert re.search(rf"\b{name}\b", c_text), f"{name}: not used by the C firmware"
        assert re.search(rf"\b{name}\b", model_text), f"{name}: not used by the model"
    assert not re.search(r"#define\s+\w*(TICKS|ROUNDS|SLOT)\b", c_text)
    ours = {n for n in vars(timing) if re.fullmatch(r"[A-Z_]+_(TICKS|ROUNDS|REPEATS|SHOWS)", n)}
    ours.discard("LOCALIZE_SLOT_GUARD_TICKS")  # part of LOCALIZE_SLOT_TICKS
    # parts of a Walter round's layout: the header has its instants (WALTER_*_AT)
    ours -= {n for n in ours if n.startswith("WALTER_")}
    assert f"#define WALTER_ROUND_TICKS {timing.walter_round_ticks(timing.Baud.IR)}" in text
    assert ours == set(cheader.PROGRAM_TIMING), "a timing in bus/timing.py the header leaves out"
    # a v2 localization slot carries the preamble, one role prefix and '*' MSG1
    from bus import codec
    assert timing.LOCALIZE_SLOT_BYTES == len(codec.PREAMBLE) + len(codec.ROLE_PREFIX["M"]) + codec.MSG1_LEN
    assert timing.LOCALIZE_MUX_SETTLE_TICKS < timing.LOCALIZE_SLOT_GUARD_TICKS
    assert f"#define LOCALIZE_STEP_TICKS {timing.localize_step_ticks(timing.Baud.IR)}" in text


def test_comm_lines_are_built_only_where_they_are_sent() -> None:
    """comm.c's one line buffer cannot be shared by two lines: a coroutine calls a line_*
    builder only inside LINE_SEND, which builds and transmits without a wait in between."""
    import re
    body = _strip_c_comments((ROOT / "firmware" / "src" / "comm.c").read_text())
    coroutines = re.findall(r"\nstatic uint8_t (co_\w+)\([^)]*\)\n\{\n(.*?)\n\}\n", body, flags=re.S)
    assert len(coroutines) > 15
    for name, code in coroutines:
        for _, args, _ in _c_calls(code, "LINE_SEND"):
            code = code.replace(f"LINE_SEND({args})", "")
        assert not re.search(r"\bline_\w+\s*\(|\bline\.", code), f"{name} builds a line outside LINE_SEND"

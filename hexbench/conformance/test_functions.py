"""Spec §6-§7: ACK bytes and port bits for the function codes; timeouts; garbage."""

import random

import pytest

from bus import codec
from bus.functions import FUNCTIONS, Board, FunctionCode as F
from bus.pins import JOINT, LED_JOINT, LED_NEG, LED_POS, MAGNET_NEG, MAGNET_POS
from bus.timing import ECHO_TIMEOUT_TICKS, TICK_NS


def _bit(ports, pin) -> bool:
    return bool(ports[pin.port] & pin.mask)


def _state(m):
    c, k = m.ctrl.port, m.comm.port
    return {
        "joint": [_bit(c, JOINT[j]) for j in range(1, 7)],
        "pos": [_bit(c, MAGNET_POS[s]) for s in range(1, 7)],
        "neg": [_bit(c, MAGNET_NEG[s]) for s in range(1, 7)],
        "led_joint": [not _bit(k, LED_JOINT[j]) for j in range(1, 7)],
        "led_pos": [not _bit(k, LED_POS[s]) for s in range(1, 7)],
        "led_neg": [not _bit(k, LED_NEG[s]) for s in range(1, 7)],
    }


def test_sxp3_sets_pb6_and_clears_pc6(hexbench_bench, hexbench_pc):
    ack = hexbench_pc.ack("SxP", 3)
    assert ack.frame.raw == b"\n\r\n\rM: ACK\x0b\n\r"
    m = hexbench_bench.module
    assert m.ctrl.port["B"] & 0x40 and not m.comm.port["C"] & 0x40


SINGLE = [  # code, args, what is on afterwards (index 0-based side/joint)
    ("JxOpen", (2,), {"joint": [1], "led_joint": [1]}),
    ("JxOpen", (8,), {"joint": [1], "led_joint": [1]}),  # i wraps into 1..6
    ("JxOpenAll", (), {"joint": range(6), "led_joint": range(6)}),
    ("SxP", (5,), {"pos": [4], "led_pos": [4]}),
    ("SxN", (4,), {"neg": [3], "led_neg": [3]}),
]


@pytest.mark.parametrize("name,args,on", SINGLE, ids=lambda v: str(v))
def test_control_code_ack_and_port_bits(hexbench_bench, hexbench_pc, name, args, on):
    code = F[name]
    ack = hexbench_pc.ack(name, *args)
    assert ack.frame.view["byte"] == code  # the control board's echo
    st = _state(hexbench_bench.module)
    for key, values in st.items():
        want = [i in set(on.get(key, [])) for i in range(6)]
        assert values == want, key


def test_off_codes_clear_what_was_on(hexbench_bench, hexbench_pc):
    m = hexbench_bench.module
    for name, args in (("SxP", (1,)), ("SxN", (2,)), ("JxOpen", (3,))):
        hexbench_pc.ack(name, *args)
    hexbench_pc.ack("SxOff", 1)
    assert not any(_state(m)["pos"]) and not any(_state(m)["led_pos"])
    hexbench_pc.ack("TurnOffAll")
    st = _state(m)
    assert not any(st["neg"] + st["joint"] + st["led_neg"] + st["led_joint"])
    assert m.ctrl.port["B"] & 0x0C == 0 and m.ctrl.port["D"] & 0x03 == 0  # UART pins untouched


@pytest.mark.parametrize("code", [c for c, f in FUNCTIONS.items() if f.board is Board.COMM
                                  and f.profile == "v1" and not f.args and c not in (F.Ref, F.Localize)])
def test_comm_codes_ack_their_own_code(hexbench_pc, code):
    assert hexbench_pc.ack(code).frame.view["byte"] == code


#: Codes the function table leaves unused, spread over the byte (new codes leave this list by
#: themselves: 17 became WalterLog).
_UNUSED = [c for c, f in sorted(FUNCTIONS.items()) if f.board is Board.UNUSED]


@pytest.mark.parametrize("code", _UNUSED[::max(1, len(_UNUSED) // 8)] + [_UNUSED[-1]])
def test_unknown_code_acks_N(hexbench_pc, code):
    assert hexbench_pc.ack(code).frame.view["byte"] == ord("N")


def test_silent_control_board_gives_tilde_after_250_ticks(hexbench_bench, hexbench_pc):
    hexbench_bench.module.ctrl.halted = True  # a control board that never echoes
    sent_end = hexbench_pc.send("SxP", 1)
    ack = hexbench_pc.expect("ack", timeout_s=5)
    assert ack.frame.view["byte"] == ord("~")
    # The thesis comm board reads 9 bytes after '*' and leaves the '#' unread; v2 reads it.
    read_end = sent_end - (hexbench_pc.byte_ns if hexbench_bench.profile == "thesis-2009" else 0)
    waited = ack.t_first_ns - read_end
    assert (ECHO_TIMEOUT_TICKS - 1) * TICK_NS < waited < (ECHO_TIMEOUT_TICKS + 3) * TICK_NS


@pytest.mark.parametrize("name,code", [("MCW", F.MCW), ("MCCW", F.MCCW), ("SCW", F.SCW), ("SCCW", F.SCCW)])
def test_rotation_port_time_series(hexbench_bench, hexbench_pc, name, code):
    """21..24: port changes at the programmed t1, t2, t3 (spec §7, Appendix A)."""
    m = hexbench_bench.module
    changes = []
    m.ctrl.on_ports = lambda mcu: changes.append((hexbench_bench.clock.now_ns(), dict(mcu.port)))
    t1, t2, t3 = 8, 4, 9
    hexbench_pc.ack(name, 3, t1, t2, t3)
    times = sorted({t for t, _ in changes})
    steps = [b - a for a, b in zip(times, times[1:])]
    expected = {"MCW": [t1, t2, t3], "MCCW": [t1, t2, t3], "SCW": [t1, t2, t3],
                "SCCW": [t1, t2, t3]}[name]
    assert len(steps) == 3
    assert steps[1:] == [e * TICK_NS for e in expected[1:]]
    assert (expected[0] - 1) * TICK_NS < steps[0] <= expected[0] * TICK_NS
    final = changes[-1][1]
    assert final["A"] & 0x3F == 0 and final["B"] & ~0x0C & 0xFF == 0 and final["D"] & ~0x03 & 0xFF == 0


def test_garbage_never_stops_the_next_valid_frame(hexbench_bench, hexbench_pc):
    rng = random.Random(hexbench_bench.profile)
    for round_ in range(5):
        # the thesis firmware takes any '*' as a frame start; v2 resynchronises on '#'
        alphabet = [b for b in range(256) if hexbench_bench.profile == "v2" or b != ord("*")]
        junk = bytes(rng.choice(alphabet) for _ in range(rng.randrange(1, 20)))
        if hexbench_bench.profile == "v2":
            junk = junk.replace(b"*", b"*#") if round_ % 2 else junk
        hexbench_pc.send_raw(junk)
        ack = hexbench_pc.ack("SideOnP", 2, timeout_s=30)
        while ack.frame.view["byte"] != F.SideOnP:  # a junk '*' frame may be acked first
            ack = hexbench_pc.expect("ack", timeout_s=30)
        assert ack.frame.view["byte"] == F.SideOnP


def test_ack_bytes_match_spec_format(hexbench_pc):
    raw = hexbench_pc.ack("LOn").frame.raw
    assert raw == codec.PREAMBLE + b"M: ACK" + bytes([F.LOn]) + codec.EOL



def test_a_frame_relayed_while_the_control_board_is_busy_is_lost_cleanly(hexbench_bench, hexbench_pc):
    """Issue 50 item 2: SelfTest answers at once and keeps the control board busy 3.6 s
    longer; a relay frame that reaches it then overruns its input. The PC gets '~' for it
    and the next command runs: no leftover '#' run as code 35, no coil command lost."""
    if hexbench_bench.profile == "thesis-2009":
        pytest.skip("SelfTest is v2's; a thesis command's LED mirror keeps the comm board as "
                    "busy as the control board, so no frame reaches a busy control board")
    pc, clock = hexbench_pc, hexbench_bench.clock
    assert pc.ack("SelfTest").frame.view["byte"] == F.SelfTest
    clock.run(until_ns=clock.now_ns() + 1_500_000_000)
    assert pc.ack("JxOpen", 2, timeout_s=10).frame.view["byte"] == ord("~")
    assert pc.ack("SxP", 3, timeout_s=10).frame.view["byte"] == F.SxP
    st = _state(hexbench_bench.module)
    assert st["pos"] == [False, False, True, False, False, False] and st["led_pos"] == st["pos"]
    assert not any(st["joint"]) and not any(st["led_joint"])  # JxOpen 2 neither run nor shown


def test_the_comm_board_takes_only_the_echo_of_the_code_it_relayed(hexbench_bench, hexbench_pc):
    """Issue 50 item 2: a stale byte waiting on UART0 and a wrong one after the relay are not
    the echo in v2: the ACK is '~' and the LEDs show nothing. The thesis board takes the first
    byte it reads, whatever it is."""
    m, clock = hexbench_bench.module, hexbench_bench.clock
    m.ctrl.halted = True  # the control board says nothing of its own
    uart, chained = m.comm.uart0, m.comm.uart0.on_tx

    def wrong_echo(data: bytes, starts: list[int]) -> None:
        if data[:1] == codec.START:
            clock.call_at(starts[-1] + 2 * uart.byte_ns, uart.receive, ord("#"))
        if chained is not None:
            chained(data, starts)

    uart.on_tx = wrong_echo
    uart.receive(F.SxP)  # an echo that came too late for an earlier relay
    ack = hexbench_pc.ack("SxP", 1, timeout_s=5).frame.view["byte"]
    led_pos = _state(m)["led_pos"]
    if hexbench_bench.profile == "thesis-2009":
        assert ack == F.SxP and led_pos[0]
    else:
        assert ack == ord("~") and not any(led_pos)


def test_a_frame_sent_after_a_silence_is_read_in_step(hexbench_bench, hexbench_pc):
    """Issue 50 item 3: a frame whose '*' was damaged, with '#', '*' among its arguments
    (t2 = 35, t3 = 42), then the same frame again after a pause. v2 ends the damaged frame at
    the silence after it, so the retry runs; the thesis board starts a frame at the argument
    '*' and takes the retry's first bytes for the rest: no retry runs (Appendix A's missing
    '#' check, kept)."""
    pc, clock = hexbench_pc, hexbench_bench.clock
    frame = codec.encode_command("MCW", 3, 8, 35, 42)
    pc.send_raw(b"+" + frame[1:])
    clock.run(until_ns=pc.line_free_at + 1_000_000_000)
    for _ in range(2):
        ack = pc.ack("MCW", 3, 8, 35, 42, timeout_s=10).frame.view["byte"]
        assert (ack == F.MCW) == (hexbench_bench.profile == "v2")
        clock.run(until_ns=clock.now_ns() + 1_000_000_000)

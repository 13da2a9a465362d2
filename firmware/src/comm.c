/* The communication board: seven IR transceivers behind a CD4051 on UART1 (300 baud),
 * the control board on UART0, LEDs active low (Tables 3-4, 3-5). Behaviour: spec sections
 * 5, 6, 9 and 13; module_sim/comm_board.py is the reference model. HEXBOT_V2 selects
 * protocol v2 (addressing, location report, general localization) or the thesis-2009
 * firmware's observable behaviour. */
#include "hexbot.h"

const uint8_t program_outputs[5] = {COMM_OUTPUTS_A, COMM_OUTPUTS_B, COMM_OUTPUTS_C,
                                    COMM_OUTPUTS_D, COMM_OUTPUTS_E};
const uint8_t program_pullups[5] = {COMM_PULLUPS_A, COMM_PULLUPS_B, COMM_PULLUPS_C,
                                    COMM_PULLUPS_D, COMM_PULLUPS_E};

static const uint8_t POS_PORT[7] FW_CONST = LED_POS_PORTS;
static const uint8_t POS_MASK[7] FW_CONST = LED_POS_MASKS;
static const uint8_t NEG_PORT[7] FW_CONST = LED_NEG_PORTS;
static const uint8_t NEG_MASK[7] FW_CONST = LED_NEG_MASKS;
static const uint8_t JNT_PORT[7] FW_CONST = LED_JOINT_PORTS;
static const uint8_t JNT_MASK[7] FW_CONST = LED_JOINT_MASKS;
static const uint8_t SEL_BITS[7] FW_CONST = IR_SEL_BITS;
#if HEXBOT_V2
static const uint8_t SW_PORT[7] FW_CONST = OPTICAL_SWITCH_PORTS;
static const uint8_t SW_MASK[7] FW_CONST = OPTICAL_SWITCH_MASKS;
static const int8_t NB_DX[7] FW_CONST = NEIGHBOUR_DX;
static const int8_t NB_DY[7] FW_CONST = NEIGHBOUR_DY;
static const int8_t CW_DX[7] FW_CONST = GOAL_CW_DX;
static const int8_t CW_DY[7] FW_CONST = GOAL_CW_DY;
static const int8_t CCW_DX[7] FW_CONST = GOAL_CCW_DX;
static const int8_t CCW_DY[7] FW_CONST = GOAL_CCW_DY;
#endif

static const char S_PREAMBLE[] FW_CONST = TXT_PREAMBLE;
static const char S_COMM_READY[] FW_CONST = TXT_COMM_READY;
static const char S_CTR_READY[] FW_CONST = TXT_CTR_READY;
static const char S_CTR_LST[] FW_CONST = TXT_CTR_LST;
static const char S_COMM_LST[] FW_CONST = TXT_COMM_LST;
static const char S_LOC[] FW_CONST = TXT_LOC;

/* the thesis firmware's globals */
static uint8_t M = 1, S, L, Yref;
static int16_t X, Y;
#if HEXBOT_V2
static uint8_t id, selected = 1, addressed, v2_active;
#endif
static uint8_t substrate_turn;
static uint8_t frame[10]; /* code and 8 arguments (and room to resynchronise) */
static uint8_t out[24];   /* a line being built for UART1: the longest, POS, is 17 bytes */

/* --- IR multiplexer and LEDs ------------------------------------------------------ */
static void IrSel(uint8_t i)
{
    if (i > 6)
        return; /* the thesis's if-chain ignores other values */
    uint8_t a = board_port(IR_SEL_PORT);
    board_port_write(IR_SEL_PORT, (uint8_t)((a & ~IR_SEL_MASK) | fw_byte(&SEL_BITS[i])));
}

/* LEDs are active low: on = bit cleared. */
static void led(const uint8_t *ports, const uint8_t *masks, int16_t i, uint8_t on)
{
    pin_change(ports, masks, i, !on);
}

static void leds(const uint8_t *ports, const uint8_t *masks, uint8_t on)
{
    pins_change(ports, masks, !on);
}

static void LOn(void)
{
    leds(POS_PORT, POS_MASK, 1);
    leds(NEG_PORT, NEG_MASK, 1);
    leds(JNT_PORT, JNT_MASK, 1);
}

static void LOff(void)
{
    leds(POS_PORT, POS_MASK, 0);
    leds(NEG_PORT, NEG_MASK, 0);
    leds(JNT_PORT, JNT_MASK, 0);
}

#if HEXBOT_V2
static uint8_t neighbour(uint8_t side)
{
    uint8_t high = (board_pins(fw_byte(&SW_PORT[side])) & fw_byte(&SW_MASK[side])) != 0;
    return OPTICAL_SWITCH_ACTIVE_LOW ? !high : high; /* a neighbour pulls it low */
}

/* The six optical switches, bit s-1 = a neighbour on side s. */
static uint8_t switch_bits(void)
{
    uint8_t bits = 0;
    for (uint8_t s = 1; s <= 6; s++)
        if (neighbour(s))
            bits |= (uint8_t)(1u << (s - 1));
    return bits;
}
#endif

/* --- UART1 lines ------------------------------------------------------------------ */
/* The preamble and role prefix every module -> PC line starts with: "S: " if S, "M: " if M. */
static uint8_t pre(uint8_t *p)
{
    uint8_t n = 0;
    for (uint8_t k = 0; k < sizeof(S_PREAMBLE) - 1; k++)
        p[n++] = fw_byte(&S_PREAMBLE[k]);
    if (S)
        p[n++] = TXT_ROLE_S[0], p[n++] = TXT_ROLE_S[1], p[n++] = TXT_ROLE_S[2];
    if (M)
        p[n++] = TXT_ROLE_M[0], p[n++] = TXT_ROLE_M[1], p[n++] = TXT_ROLE_M[2];
    return n;
}

static uint8_t out_len, pre_len;

/* --- LED animations --------------------------------------------------------------- */
static pt_t pt_anim;
static uint8_t an_round, an_k;

/* SidePTest, SideNTest, JointTest: each LED of a kind on t ticks, off t ticks, n rounds. */
static uint8_t co_blink(const uint8_t *ports, const uint8_t *masks, uint8_t n, uint8_t t)
{
    pt_t *pt = &pt_anim;
    PT_BEGIN(pt);
    for (an_round = 0; an_round < n; an_round++) {
        for (an_k = 1; an_k <= 6; an_k++) {
            led(ports, masks, an_k, 1);
            DELAY(pt, t);
            led(ports, masks, an_k, 0);
            DELAY(pt, t);
        }
    }
    PT_END(pt);
}

/* LCircle: joint LED, a probe (0xFF, 0x00) on every side, magnet LEDs. */
static pt_t pt_circle;
static uint8_t ci_round, ci_k;
static const uint8_t PROBE[2] = PROBE_BYTES;

static uint8_t co_circle(uint8_t n, uint8_t t)
{
    pt_t *pt = &pt_circle;
    PT_BEGIN(pt);
    for (ci_round = 0; ci_round < n; ci_round++) {
        for (ci_k = 1; ci_k <= 6; ci_k++) {
            led(JNT_PORT, JNT_MASK, ci_k, 1);
            DELAY(pt, t);
            led(JNT_PORT, JNT_MASK, ci_k, 0);
            DELAY(pt, t);
            IrSel(ci_k);
            TX(pt, UART1, &PROBE[0], 1);
            DELAY(pt, t);
            TX(pt, UART1, &PROBE[1], 1);
            DELAY(pt, t);
            led(NEG_PORT, NEG_MASK, ci_k, 1);
            DELAY(pt, t);
            led(NEG_PORT, NEG_MASK, ci_k, 0);
            DELAY(pt, t);
            led(POS_PORT, POS_MASK, ci_k, 1);
            DELAY(pt, t);
            led(POS_PORT, POS_MASK, ci_k, 0);
            DELAY(pt, t);
        }
    }
    IrSel(0);
    PT_END(pt);
}

/* LColor's three kinds in turn: joint, negative, positive LEDs. */
static void color_leds(uint8_t kind, uint8_t on)
{
    if (kind == 0)
        leds(JNT_PORT, JNT_MASK, on);
    else if (kind == 1)
        leds(NEG_PORT, NEG_MASK, on);
    else
        leds(POS_PORT, POS_MASK, on);
}

/* LColor, LFlash1, LFlash2 */
static uint8_t co_flash(uint8_t code, uint8_t n, uint8_t t)
{
    pt_t *pt = &pt_anim;
    PT_BEGIN(pt);
    for (an_round = 0; an_round < n; an_round++) {
        if (code == FC_LColor) {
            for (an_k = 0; an_k < 3; an_k++) {
                color_leds(an_k, 1);
                DELAY(pt, t);
                color_leds(an_k, 0);
                DELAY(pt, t);
            }
        } else if (code == FC_LFlash1) {
            leds(NEG_PORT, NEG_MASK, 1);
            leds(POS_PORT, POS_MASK, 0);
            DELAY(pt, t);
            leds(NEG_PORT, NEG_MASK, 0);
            leds(POS_PORT, POS_MASK, 1);
            DELAY(pt, t);
        } else {
            LOn();
            DELAY(pt, t);
            LOff();
            DELAY(pt, t);
        }
    }
    if (code == FC_LFlash1)
        LOff();
    PT_END(pt);
}

/* LYref(i): i = 1 turns Yref by +1, 2 by -1; then flash the side that faces global +Y. */
static pt_t pt_yref;
static uint8_t yref_side;

static uint8_t co_yref(uint8_t i)
{
    pt_t *pt = &pt_yref;
    PT_BEGIN(pt);
    if (i == 1)
        Yref = (uint8_t)((Yref + 1) % 6);
    else if (i == 2)
        Yref = (uint8_t)((Yref + 5) % 6);
    yref_side = fold(2 - (int16_t)Yref);
    led(POS_PORT, POS_MASK, yref_side, 1);
    led(NEG_PORT, NEG_MASK, yref_side, 0);
    DELAY(pt, 10);
    led(NEG_PORT, NEG_MASK, yref_side, 1);
    led(POS_PORT, POS_MASK, yref_side, 0);
    DELAY(pt, 10);
    led(NEG_PORT, NEG_MASK, yref_side, 0);
    PT_END(pt);
}

/* Three LYref(0): show the orientation. */
static pt_t pt_show;
static uint8_t show_k;

static uint8_t co_show_yref(void)
{
    pt_t *pt = &pt_show;
    PT_BEGIN(pt);
    for (show_k = 0; show_k < 3; show_k++) {
        PT_CALL(pt, co_yref(0));
    }
    PT_END(pt);
}

/* LMCW..LSCCW: a rotation replayed on the LEDs with the same waits. */
static void mirror_act(uint8_t op, int16_t i)
{
    switch (op) {
    case ROT_OPEN: led(JNT_PORT, JNT_MASK, i, 1); break;
    case ROT_POS: led(POS_PORT, POS_MASK, i, 1); break;
    case ROT_NEG: led(NEG_PORT, NEG_MASK, i, 1); break;
    case ROT_CLOSE_ALL: leds(JNT_PORT, JNT_MASK, 0); break;
    default: leds(POS_PORT, POS_MASK, 0); leds(NEG_PORT, NEG_MASK, 0); break;
    }
}

static pt_t pt_mirror;

/* --- relay to the control board ----------------------------------------------------- */
static pt_t pt_relay;
static uint8_t relay_frame[RELAY_FRAME_LEN], relay_result;

/* MSG(): '*' code a b c d '#' on UART0 (unused arguments 'N'), then wait for the echo. */
static uint8_t co_relay(uint8_t code, const uint8_t *a)
{
    pt_t *pt = &pt_relay;
    PT_BEGIN(pt);
    relay_frame[0] = BYTE_START;
    relay_frame[1] = code;
    for (uint8_t k = 0; k < 4; k++)
        relay_frame[2 + k] = k < fn_nargs(code) ? a[k] : ARG_UNUSED;
    if (code == FC_JxOpenAll || code == FC_JxCloseAll)
        relay_frame[2] = 0; /* these two send 0, not 'N', first (Appendix A) */
#if HEXBOT_V2
    if (code == FC_SelfTest)
        relay_frame[2] = switch_bits(); /* the control board reports them with the DIP id */
#endif
    relay_frame[6] = BYTE_END;
    TX(pt, UART0, relay_frame, RELAY_FRAME_LEN);
    RX_TL(pt, UART0, ECHO_TIMEOUT_TICKS, relay_result);
    PT_END(pt);
}

/* A rotation on this module: relay `code` with (i, t1, t2, t3), then its LED mirror. */
static pt_t pt_rotate;
static uint8_t rot_args[4], rot_code, rot_ack;

static uint8_t co_rotate(uint8_t code, uint8_t i, uint8_t t1, uint8_t t2, uint8_t t3)
{
    pt_t *pt = &pt_rotate;
    PT_BEGIN(pt);
    rot_code = code;
    rot_args[0] = i, rot_args[1] = t1, rot_args[2] = t2, rot_args[3] = t3;
    PT_CALL(pt, co_relay(rot_code, rot_args));
    rot_ack = relay_result;
    PT_CALL(pt, co_rotation(&pt_mirror, rotation_steps(rot_code), rot_args[0], &rot_args[1], mirror_act));
    PT_END(pt);
}

/* CW (67) / CCW (68): a mobile runs MCW/MCCW(mi..), a substrate SCW/SCCW(si..). */
static pt_t pt_turn;
static uint8_t turn_ack;

static uint8_t co_turn(uint8_t code, const uint8_t *a)
{
    pt_t *pt = &pt_turn;
    PT_BEGIN(pt);
    turn_ack = ACK_UNKNOWN; /* C leaves it uninitialised when M = S = 0; we say 'N' */
    if (M == 1) {
        PT_CALL(pt, co_rotate(code == FC_CW ? FC_MCW : FC_MCCW, a[4], a[5], a[6], a[7]));
        turn_ack = rot_ack;
    }
    if (S == 1) {
        PT_CALL(pt, co_rotate(code == FC_CW ? FC_SCW : FC_SCCW, a[0], a[1], a[2], a[3]));
        turn_ack = rot_ack;
    }
    PT_END(pt);
}

/* --- localization ---------------------------------------------------------------- */
static pt_t pt_loc, pt_report;
static uint8_t loc_side, loc_w, loc_byte, loc_heard, loc_body[MSG1_LEN];
#if HEXBOT_V2
static uint16_t loc_t0;
#endif

/* After a successful localization: "LOCALIZED", "Side: s", "Yref: y", show Yref. */
static uint8_t co_report_localized(uint8_t side)
{
    pt_t *pt = &pt_report;
    PT_BEGIN(pt);
    IrSel(0);
    out_len = pre(out);
    TX(pt, UART1, out, out_len);
    TX_P(pt, UART1, S_LOC);
    for (out_len = 0; out_len < 6; out_len++)
        out[out_len] = (uint8_t)TXT_SIDE[out_len];
    out[6] = (uint8_t)(side + '0'), out[7] = TXT_EOL[0], out[8] = TXT_EOL[1];
    TX(pt, UART1, out, 9);
    for (out_len = 0; out_len < 6; out_len++)
        out[out_len] = (uint8_t)TXT_YREF[out_len];
    out[6] = (uint8_t)(Yref + '0');
    TX(pt, UART1, out, 9);
    PT_CALL(pt, co_show_yref());
    PT_END(pt);
}

#if HEXBOT_V2
static void msg1_digits(uint8_t *p, int16_t x, int16_t y, uint8_t side)
{
    int16_t ax = x < 0 ? -x : x, ay = y < 0 ? -y : y;
    p[0] = x < 0, p[1] = (uint8_t)(ax / 10 % 10), p[2] = (uint8_t)(ax % 10);
    p[3] = y < 0, p[4] = (uint8_t)(ay / 10 % 10), p[5] = (uint8_t)(ay % 10);
    p[6] = side;
}
#endif

#if !HEXBOT_V2
/* Appendix A's Localize(): a localized module sends fixed MSG1s on sides 2 and 3; a
 * listener takes X from the tens digit and Y from the units digit (spec section 12). */
static const uint8_t THESIS_MSG1[2][7] FW_CONST = {{0, 0, 0, 0, 0, 1, 5}, {0, 0, 1, 0, 0, 0, 6}};

static uint8_t co_localize(void)
{
    pt_t *pt = &pt_loc;
    PT_BEGIN(pt);
    if (L == 1) {
        for (loc_w = 0; loc_w < 6; loc_w++) {
            for (loc_side = 2; loc_side <= 3; loc_side++) {
                led(POS_PORT, POS_MASK, loc_side, 1);
                led(NEG_PORT, NEG_MASK, loc_side, 1);
                IrSel(loc_side);
                for (loc_heard = 0; loc_heard < 2; loc_heard++) {
                    DELAY(pt, 5);
                    pre_len = out_len = pre(out);
                    out[out_len++] = BYTE_START;
                    for (uint8_t k = 0; k < 7; k++)
                        out[out_len++] = fw_byte(&THESIS_MSG1[loc_side - 2][k]);
                    TX(pt, UART1, out, pre_len); /* two transmissions, as the thesis's two */
                    TX(pt, UART1, out + pre_len, MSG1_LEN);
                }
                led(POS_PORT, POS_MASK, loc_side, 0);
                led(NEG_PORT, NEG_MASK, loc_side, 0);
            }
        }
        IrSel(0);
        PT_EXIT(pt);
    }
    for (loc_w = 1; loc_w < 7; loc_w++) {
        IrSel(loc_w);
        led(POS_PORT, POS_MASK, loc_w, 1);
        led(NEG_PORT, NEG_MASK, loc_w, 1);
        do {
            RX_TL(pt, UART1, LOCALIZE_LISTEN_TICKS, loc_byte);
        } while (loc_byte != BYTE_START && loc_byte != ACK_TIMEOUT);
        if (loc_byte == BYTE_START) {
            for (loc_side = 1; loc_side < MSG1_LEN; loc_side++) {
                RX(pt, UART1, loc_body[loc_side]);
            }
            X = loc_body[2], Y = loc_body[6]; /* the firmware's digits (a defect) */
            Yref = (uint8_t)((((int16_t)loc_body[7] - loc_w) % 6 + 6) % 6);
            L = 1;
            loc_w = 7;
            IrSel(0);
            LOff();
        }
        led(POS_PORT, POS_MASK, loc_w, 0); /* after success loc_w is 7: side 1, as in C */
        led(NEG_PORT, NEG_MASK, loc_w, 0);
    }
    if (L == 1) {
        PT_CALL(pt, co_report_localized(loc_body[7]));
    } else {
        PT_CALL(pt, co_circle(1, 5));
    }
    IrSel(0);
    PT_END(pt);
}
#else
/* One step of general localization (Table 4-1, all six sides, optical switches). Every
 * module that heard the broadcast starts together; time is cut into 6 listener windows
 * of 6 sender slots. In window w a module that is not localized listens on body side w;
 * in slot s of each window a localized one sends MSG1 on body side s. Sides without a
 * neighbour stay dark. */
#define SLOT LOCALIZE_SLOT_TICKS

/* Ticks until the overflow that makes board_ticks() == target, at least 1. */
static uint16_t ticks_until(uint16_t target)
{
    int16_t n = (int16_t)(target - board_ticks());
    return n < 1 ? 1 : (uint16_t)n;
}

/* MSG1 after '*' (body[1..7]): sign, tens, units of X and of Y, then the side. */
static uint8_t msg1_valid(const uint8_t *body)
{
    return body[1] <= 1 && body[2] <= 9 && body[3] <= 9 && body[4] <= 1 && body[5] <= 9
        && body[6] <= 9 && body[7] >= 1 && body[7] <= 6;
}

static int16_t msg1_coord(const uint8_t *p)
{
    int16_t v = (int16_t)(10 * p[1] + p[2]);
    return p[0] ? (int16_t)-v : v;
}
static uint8_t co_localize(void)
{
    pt_t *pt = &pt_loc;
    PT_BEGIN(pt);
    loc_t0 = board_ticks();
    if (L == 1) {
        for (loc_w = 0; loc_w < 6; loc_w++) {
            for (loc_side = 1; loc_side <= 6; loc_side++) {
                WAIT_TICK(pt, (uint16_t)(loc_t0 + (6u * loc_w + loc_side - 1) * SLOT));
                if (!neighbour(loc_side))
                    continue;
                IrSel(loc_side);
                DELAY(pt, 2); /* more than the 0.38 ms multiplexer gap; the listener is there */
                {
                    uint8_t g = fold(loc_side + Yref), facing = fold(g + 3);
                    pre_len = out_len = pre(out);
                    out[out_len++] = BYTE_START;
                    msg1_digits(&out[out_len], X + fw_sbyte(&NB_DX[g]), Y + fw_sbyte(&NB_DY[g]), facing);
                }
                TX(pt, UART1, out, pre_len); /* preamble and role, then '*' MSG1 */
                TX(pt, UART1, out + pre_len, MSG1_LEN);
            }
        }
        WAIT_TICK(pt, (uint16_t)(loc_t0 + 36u * SLOT));
        IrSel(0);
        PT_EXIT(pt);
    }
    loc_heard = 0;
    for (loc_w = 1; loc_w <= 6; loc_w++) {
        if (!neighbour(loc_w))
            continue;
        WAIT_TICK(pt, (uint16_t)(loc_t0 + 6u * (loc_w - 1) * SLOT));
        IrSel(loc_w);
        do {
            RX_TL(pt, UART1, ticks_until((uint16_t)(loc_t0 + 6u * loc_w * SLOT)), loc_byte);
        } while (loc_byte != BYTE_START && loc_byte != ACK_TIMEOUT);
        if (loc_byte != BYTE_START)
            continue;
        for (loc_side = 1; loc_side < MSG1_LEN; loc_side++) {
            RX_TL(pt, UART1, HANDSHAKE_RETRY_TICKS, loc_body[loc_side]);
        }
        if (!msg1_valid(loc_body))
            continue;
        X = msg1_coord(&loc_body[1]), Y = msg1_coord(&loc_body[4]);
        Yref = (uint8_t)((((int16_t)loc_body[7] - loc_w) % 6 + 6) % 6);
        L = 1;
        loc_heard = loc_body[7];
        break;
    }
    IrSel(0);
    if (L && loc_heard && !v2_active) {
        PT_CALL(pt, co_report_localized(loc_heard)); /* v1 PCs see the thesis report lines */
    }
    PT_END(pt);
}
#endif

/* Ref(): become the reference module, then show the orientation. */
static uint8_t co_ref(void)
{
    if (pt_show.lc == 0) {
        M = 0, S = 1, L = 1;
        X = Y = 0;
        Yref = 0;
    }
    return co_show_yref();
}

#if HEXBOT_V2
/* --- protocol v2: addressing, location report, addressed moves (docs/protocol.md) --- */
static pt_t pt_pos;

/* Report(): preamble, role, "POS" id x+128 y+128 yref flags, EOL. */
static uint8_t co_position(void)
{
    pt_t *pt = &pt_pos;
    PT_BEGIN(pt);
    out_len = pre(out);
    out[out_len++] = TXT_POS[0], out[out_len++] = TXT_POS[1], out[out_len++] = TXT_POS[2];
    out[out_len++] = id;
    out[out_len++] = (uint8_t)(X + COORD_OFFSET);
    out[out_len++] = (uint8_t)(Y + COORD_OFFSET);
    out[out_len++] = (uint8_t)(Yref % 6);
    out[out_len++] = (uint8_t)((L ? 1 : 0) | (M ? 2 : 0) | (S ? 4 : 0));
    out[out_len++] = TXT_EOL[0], out[out_len++] = TXT_EOL[1];
    TX(pt, UART1, out, out_len);
    PT_END(pt);
}

/* Version(): preamble, role, "VER" major minor profile, EOL. */
static uint8_t co_version(void)
{
    pt_t *pt = &pt_pos;
    PT_BEGIN(pt);
    out_len = pre(out);
    out[out_len++] = TXT_VER[0], out[out_len++] = TXT_VER[1], out[out_len++] = TXT_VER[2];
    out[out_len++] = FIRMWARE_VERSION_MAJOR, out[out_len++] = FIRMWARE_VERSION_MINOR;
    out[out_len++] = PROFILE_V2_BYTE;
    out[out_len++] = TXT_EOL[0], out[out_len++] = TXT_EOL[1];
    TX(pt, UART1, out, out_len);
    PT_END(pt);
}

/* Select(mode, a, b): which modules obey the frames that follow. */
static void select_modules(uint8_t mode, uint8_t a, uint8_t b)
{
    v2_active = 1;
    if (mode == 0) {
        selected = 1, addressed = 0;
    } else if (mode == 1) {
        selected = addressed = (a == id);
    } else if (mode == 2) {
        selected = addressed = L && X == (int16_t)a - COORD_OFFSET && Y == (int16_t)b - COORD_OFFSET;
    } else if (mode == 3) {
        if (a == id)
            selected = addressed = 1;
    } else {
        selected = addressed = 0;
    }
}

/* A localized mobile module keeps its location through a Move it executed: the Table 4-3
 * goal of the rotation about its body joint mi. The PC compares; the module cannot know. */
static void moved(uint8_t mi, uint8_t cw)
{
    uint8_t j = fold(mi + Yref);
    X += fw_sbyte(cw ? &CW_DX[j] : &CCW_DX[j]);
    Y += fw_sbyte(cw ? &CW_DY[j] : &CCW_DY[j]);
    Yref = (uint8_t)((Yref + (cw ? ORIENTATION_STEP_CW : 6 - ORIENTATION_STEP_CW)) % 6);
}

/* Move(dir, mid, mi, sid, si, t1, t2, t3): the two named modules act at once. */
static pt_t pt_move;
static uint8_t move_ack, move_has_ack;

static uint8_t co_move(const uint8_t *a)
{
    pt_t *pt = &pt_move;
    PT_BEGIN(pt);
    move_has_ack = 1;
    if (id == a[1]) {
        PT_CALL(pt, co_rotate(a[0] == 1 ? FC_MCW : FC_MCCW, a[2], a[5], a[6], a[7]));
        move_ack = rot_ack;
        if (L && (move_ack == FC_MCW || move_ack == FC_MCCW))
            moved(a[2], a[0] == 1);
    } else if (id == a[3]) {
        substrate_turn = 1;
        PT_CALL(pt, co_rotate(a[0] == 1 ? FC_SCW : FC_SCCW, a[4], a[5], a[6], a[7]));
        move_ack = rot_ack;
    } else {
        move_has_ack = 0;
    }
    PT_END(pt);
}
#endif

/* --- Listen(): one frame from the PC ------------------------------------------------- */
/* Run a comm-board code; PT_DONE when finished (at once for the instant ones). */
static uint8_t run_comm(uint8_t code, const uint8_t *a)
{
    switch (code) {
    case FC_IrSel: IrSel(a[0]); return PT_DONE;
    case FC_SideOnP: led(POS_PORT, POS_MASK, a[0], 1); return PT_DONE;
    case FC_SideOffP: led(POS_PORT, POS_MASK, a[0], 0); return PT_DONE;
    case FC_SideOnAllP: leds(POS_PORT, POS_MASK, 1); return PT_DONE;
    case FC_SideOffAllP: leds(POS_PORT, POS_MASK, 0); return PT_DONE;
    case FC_SideOnN: led(NEG_PORT, NEG_MASK, a[0], 1); return PT_DONE;
    case FC_SideOffN: led(NEG_PORT, NEG_MASK, a[0], 0); return PT_DONE;
    case FC_SideOnAllN: leds(NEG_PORT, NEG_MASK, 1); return PT_DONE;
    case FC_SideOffAllN: leds(NEG_PORT, NEG_MASK, 0); return PT_DONE;
    case FC_JointOn: led(JNT_PORT, JNT_MASK, a[0], 1); return PT_DONE;
    case FC_JointOff: led(JNT_PORT, JNT_MASK, a[0], 0); return PT_DONE;
    case FC_JointOnAll: leds(JNT_PORT, JNT_MASK, 1); return PT_DONE;
    case FC_JointOffAll: leds(JNT_PORT, JNT_MASK, 0); return PT_DONE;
    case FC_LOn: LOn(); return PT_DONE;
    case FC_LOff: LOff(); return PT_DONE;
    case FC_SidePTest: return co_blink(POS_PORT, POS_MASK, a[0], a[1]);
    case FC_SideNTest: return co_blink(NEG_PORT, NEG_MASK, a[0], a[1]);
    case FC_JointTest: return co_blink(JNT_PORT, JNT_MASK, a[0], a[1]);
    case FC_LCircle: return co_circle(a[0], a[1]);
    case FC_LColor: case FC_LFlash1: case FC_LFlash2: return co_flash(code, a[0], a[1]);
    case FC_LYref: return co_yref(a[0]);
    case FC_LMCW: case FC_LMCCW: case FC_LSCW: case FC_LSCCW:
        return co_rotation(&pt_mirror, rotation_steps(code), a[0], &a[1], mirror_act);
    case FC_Ref: return co_ref();
    case FC_Localize: return co_localize();
    case FC_CW: case FC_CCW: return co_turn(code, a);
#if HEXBOT_V2
    case FC_Report: return co_position();
    case FC_Version: return co_version();
#endif
    default: return PT_DONE;
    }
}

static pt_t pt_dispatch;
static uint8_t d_board, d_ack, d_has_ack, d_k;

/* Execute frame[] and decide the ACK byte (d_has_ack = 0: stay silent). */
static uint8_t co_dispatch(void)
{
    pt_t *pt = &pt_dispatch;
    PT_BEGIN(pt);
    d_has_ack = 1;
    d_board = fn_board(frame[0]);
#if HEXBOT_V2
    if (frame[0] == FC_Select) {
        select_modules(frame[1], frame[2], frame[3]);
        d_ack = frame[0];
        d_has_ack = addressed;
        PT_EXIT(pt);
    }
    if (frame[0] == FC_Move) {
        PT_CALL(pt, co_move(&frame[1]));
        d_ack = move_ack, d_has_ack = move_has_ack;
        PT_EXIT(pt);
    }
    if (!selected) {
        d_has_ack = 0;
        PT_EXIT(pt);
    }
#else
    if (fn_is_v2(frame[0]))
        d_board = BOARD_NONE; /* a thesis module does not know our codes */
#endif
    if (d_board == BOARD_CONTROL) {
        PT_CALL(pt, co_relay(frame[0], &frame[1]));
        d_ack = relay_result;
        for (d_k = 0; d_k < 2; d_k++) {
            PT_CALL(pt, run_comm(fn_mirror(frame[0], d_k), &frame[1]));
        }
    } else if (d_board == BOARD_COMM) {
        PT_CALL(pt, run_comm(frame[0], &frame[1]));
        d_ack = frame[0] == FC_CW || frame[0] == FC_CCW ? turn_ack : frame[0];
    } else {
        d_ack = ACK_UNKNOWN;
    }
#if HEXBOT_V2
    if (v2_active && !addressed)
        d_has_ack = 0; /* a broadcast: answers would collide on the centre channel */
#endif
    PT_END(pt);
}

static pt_t pt_listen;
static uint8_t l_byte, l_n;

#if HEXBOT_V2
/* The frame did not end in '#': it was garbage with a '*' in it. Keep what follows the
 * first '*' among frame[1..8] and the byte read in place of '#'; 0 if there is none. */
static uint8_t resync(void)
{
    for (uint8_t k = 0; k < 10; k++) {
        if (frame[k] == BYTE_START) {
            uint8_t n = 0;
            for (uint8_t j = k + 1; j < 10; j++)
                frame[n++] = frame[j];
            return n;
        }
    }
    return 0xFF;
}
#endif

static uint8_t co_listen(void)
{
    pt_t *pt = &pt_listen;
    PT_BEGIN(pt);
    do {
        RX(pt, UART1, l_byte);
    } while (l_byte != BYTE_START);
    for (l_n = 0; l_n < 9; l_n++) {
        RX(pt, UART1, frame[l_n]);
    }
#if HEXBOT_V2
    /* v2 reads the '#' too and resynchronises on a '*' inside a frame that lacks it */
    RX(pt, UART1, frame[9]);
    while (frame[9] != BYTE_END) {
        l_n = resync();
        if (l_n == 0xFF)
            PT_EXIT(pt);
        while (l_n < 9) {
            RX(pt, UART1, frame[l_n]);
            l_n++;
        }
        RX(pt, UART1, frame[9]);
    }
#endif
    substrate_turn = 0;
    PT_CALL(pt, co_dispatch());
    if (!d_has_ack)
        PT_EXIT(pt);
    if (S || substrate_turn) {
        DELAY(pt, SUBSTRATE_ACK_DELAY_TICKS); /* let the mobile module answer first */
    }
    out_len = pre(out);
    out[out_len++] = TXT_ACK[0], out[out_len++] = TXT_ACK[1], out[out_len++] = TXT_ACK[2];
    out[out_len++] = d_ack;
    out[out_len++] = TXT_EOL[0], out[out_len++] = TXT_EOL[1];
    TX(pt, UART1, out, out_len);
    PT_END(pt);
}

/* --- main ------------------------------------------------------------------------------ */
static pt_t pt_main;
static uint8_t m_byte;
#if HEXBOT_V2
static uint8_t m_timed_out;
#endif

static uint8_t co_main(void)
{
    pt_t *pt = &pt_main;
    PT_BEGIN(pt);
    LOff();
    IrSel(0);
    out_len = pre(out);
    TX(pt, UART1, out, out_len);
    TX_P(pt, UART1, S_COMM_READY);
    do {
        RX(pt, UART0, m_byte);
    } while (m_byte != BYTE_READY);
    PT_CALL(pt, co_flash(FC_LFlash1, 3, 10));
    TX_P(pt, UART1, S_CTR_READY);
    m_byte = BYTE_READY;
    TX(pt, UART0, &m_byte, 1);
    for (;;) {
        RX_TL(pt, UART0, HANDSHAKE_RETRY_TICKS, m_byte);
        if (m_byte == BYTE_LISTENING)
            break;
        m_byte = BYTE_READY;
        TX(pt, UART0, &m_byte, 1);
    }
#if HEXBOT_V2
    /* the control board's DIP switches: any byte is an id, '~' (126) too; silence is none */
    RX_TL2(pt, UART0, HANDSHAKE_RETRY_TICKS, m_byte, m_timed_out);
    id = m_timed_out ? 0 : m_byte;
#endif
    PT_CALL(pt, co_flash(FC_LFlash2, 3, 10));
    TX_P(pt, UART1, S_CTR_LST);
    PT_CALL(pt, co_circle(1, 5));
#if !HEXBOT_V2
    Yref = 1; /* the thesis assumed its test orientation instead of localizing */
#endif
    IrSel(0);
    TX_P(pt, UART1, S_LOC); /* v2 keeps the banner for v1 PCs; it no longer claims L = 1 */
    IrSel(0);
    PT_CALL(pt, co_flash(FC_LColor, 3, 10));
    TX_P(pt, UART1, S_COMM_LST);
    for (;;) {
        PT_CALL(pt, co_listen());
    }
    PT_END(pt);
}

void program_step(void)
{
    co_main();
}

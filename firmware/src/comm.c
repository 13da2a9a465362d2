/* The communication board: seven IR transceivers behind a CD4051 on UART1 (300 baud),
 * the control board on UART0, LEDs active low (Tables 3-4, 3-5). Behaviour: spec sections
 * 5, 6, 9 and 13; module_sim/comm_board.py is the reference model. HEXBOT_V2 selects
 * protocol v2 (addressing, location report, general localization) or the thesis-2009
 * firmware's observable behaviour.
 *
 * How it runs: program_step() (at the end) runs co_program: the boot (banners, the
 * handshake with the control board, LED shows), then co_listen forever: one frame from the
 * PC, co_dispatch, the ACK. co_dispatch relays a control-board code (co_relay) and runs its
 * LED mirror, or runs a comm-board code (run_comm): an LED show, co_localize, co_turn
 * (co_rotate), and in v2 Select, co_move and the Report and Version lines.
 *
 * Each coroutine keeps its state in one struct named after it, declared just above it: its
 * pt_t (where it waits) and the locals that live across a wait. What it leaves for its
 * caller (relay.result, rotate.ack, dispatch.ack, ...) is read there after its PT_CALL.
 * Every line to the PC is built and sent by LINE_SEND, one burst at a time. Waits and
 * show lengths are bus/timing.py's, through hexbot_gen.h. */
#include <string.h>

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
static const char S_SIDE[] FW_CONST = TXT_SIDE;
static const char S_YREF[] FW_CONST = TXT_YREF;

/* --- the module: the thesis firmware's globals, v2's addressing, the frame being run ----- */
static uint8_t M = 1, S, L, Yref; /* mobile, substrate, localized; orientation 0..5 */
static int16_t X, Y;              /* the module's cell once localized */
#if HEXBOT_V2
static uint8_t id, selected = 1, addressed, v2_active; /* DIP id; what Select decided */
#endif
static uint8_t frame[10];      /* from the PC: code and 8 arguments (and room to resynchronise) */
static uint8_t substrate_turn; /* this frame's Move made us its substrate: ACK after the mobile */

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

/* --- lines to the PC (UART1), one burst at a time ----------------------------------- */
/* A burst (one transmission, as one Tx of the model) is built into `line` by a line_*
 * builder and handed to UART1 in the same statement: LINE_SEND(pt, line_ack(ack)). A
 * coroutine waits only inside LINE_SEND, so no burst can be built while another is still
 * going into UDR: two lines cannot share the buffer. The builders are called only inside
 * LINE_SEND (tests/firmware/test_header.py holds this). */
#define PRE_MAX (sizeof(S_PREAMBLE) - 1 + sizeof(TXT_ROLE_S) - 1 + sizeof(TXT_ROLE_M) - 1)

static struct {
    uint8_t buf[PRE_MAX + 10]; /* the longest line, POS: pre, "POS", 5 bytes, EOL */
    uint8_t len;
} line;

#define LINE_SEND(pt, build) \
    do { line.len = 0; build; TX(pt, UART1, line.buf, line.len); } while (0)

/* Builders append with these, kept quick: a burst's first byte waits for all of it. */
#define LINE_INLINE static inline __attribute__((always_inline))

LINE_INLINE void line_add(uint8_t b)
{
    line.buf[line.len++] = b;
}

/* a three-letter text of hexbot_gen.h ("ACK", "M: "): three constant bytes */
LINE_INLINE void line_add3(const char *t)
{
    line_add((uint8_t)t[0]), line_add((uint8_t)t[1]), line_add((uint8_t)t[2]);
}

LINE_INLINE void line_eol(void)
{
    line_add(TXT_EOL[0]), line_add(TXT_EOL[1]);
}

/* n bytes of a FW_CONST table or string */
static void line_add_P(const void *flash, uint8_t n)
{
    const uint8_t *from = (const uint8_t *)flash;
    uint8_t *to = line.buf + line.len;
    line.len = (uint8_t)(line.len + n);
    while (n--) {
        *to++ = fw_byte(from);
        from++;
    }
}

/* a FW_CONST string without its NUL */
#define line_text(s) line_add_P(s, sizeof(s) - 1)

/* The preamble and role prefix every module -> PC line starts with: "S: " if S, "M: " if M. */
static void line_pre(void)
{
    line_text(S_PREAMBLE);
    if (S)
        line_add3(TXT_ROLE_S);
    if (M)
        line_add3(TXT_ROLE_M);
}

/* pre, "ACK", the code, EOL */
static void line_ack(uint8_t ack)
{
    line_pre();
    line_add3(TXT_ACK);
    line_add(ack);
    line_eol();
}

/* "Side: s" or "Yref: y", EOL: a localization report (flash label, one digit). */
_Static_assert(sizeof(S_SIDE) == sizeof(S_YREF), "the two report labels are one length");

static void line_report(const char *label, uint8_t digit)
{
    line_add_P(label, sizeof(S_SIDE) - 1);
    line_add((uint8_t)(digit + '0'));
    line_eol();
}

/* --- LED shows --------------------------------------------------------------------- */
/* SidePTest, SideNTest, JointTest: each LED of a kind on t ticks, off t ticks, n rounds. */
static struct { pt_t pt; uint8_t round, k; } blink;

static uint8_t co_blink(const uint8_t *ports, const uint8_t *masks, uint8_t n, uint8_t t)
{
    pt_t *pt = &blink.pt;
    PT_BEGIN(pt);
    for (blink.round = 0; blink.round < n; blink.round++) {
        for (blink.k = 1; blink.k <= 6; blink.k++) {
            led(ports, masks, blink.k, 1);
            DELAY(pt, t);
            led(ports, masks, blink.k, 0);
            DELAY(pt, t);
        }
    }
    PT_END(pt);
}

/* LCircle: joint LED, a probe (0xFF, 0x00) on every side, magnet LEDs. */
static const uint8_t PROBE[2] = PROBE_BYTES;
static struct { pt_t pt; uint8_t round, k; } circle;

static uint8_t co_circle(uint8_t n, uint8_t t)
{
    pt_t *pt = &circle.pt;
    PT_BEGIN(pt);
    for (circle.round = 0; circle.round < n; circle.round++) {
        for (circle.k = 1; circle.k <= 6; circle.k++) {
            led(JNT_PORT, JNT_MASK, circle.k, 1);
            DELAY(pt, t);
            led(JNT_PORT, JNT_MASK, circle.k, 0);
            DELAY(pt, t);
            IrSel(circle.k);
            TX(pt, UART1, &PROBE[0], 1);
            DELAY(pt, t);
            TX(pt, UART1, &PROBE[1], 1);
            DELAY(pt, t);
            led(NEG_PORT, NEG_MASK, circle.k, 1);
            DELAY(pt, t);
            led(NEG_PORT, NEG_MASK, circle.k, 0);
            DELAY(pt, t);
            led(POS_PORT, POS_MASK, circle.k, 1);
            DELAY(pt, t);
            led(POS_PORT, POS_MASK, circle.k, 0);
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

/* LColor, LFlash1, LFlash2: n rounds, t ticks a phase. */
static struct { pt_t pt; uint8_t round, kind; } flash;

static uint8_t co_flash(uint8_t code, uint8_t n, uint8_t t)
{
    pt_t *pt = &flash.pt;
    PT_BEGIN(pt);
    for (flash.round = 0; flash.round < n; flash.round++) {
        if (code == FC_LColor) {
            for (flash.kind = 0; flash.kind < 3; flash.kind++) {
                color_leds(flash.kind, 1);
                DELAY(pt, t);
                color_leds(flash.kind, 0);
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

/* LYref(i): turn Yref by +1 (YREF_PLUS), -1 (YREF_MINUS) or not at all (YREF_KEEP), then
 * flash the side that faces global +Y. */
enum { YREF_KEEP = 0, YREF_PLUS = 1, YREF_MINUS = 2 };
static struct { pt_t pt; uint8_t side; } lyref;

static uint8_t co_lyref(uint8_t i)
{
    pt_t *pt = &lyref.pt;
    PT_BEGIN(pt);
    if (i == YREF_PLUS)
        Yref = (uint8_t)((Yref + 1) % 6);
    else if (i == YREF_MINUS)
        Yref = (uint8_t)((Yref + 5) % 6);
    lyref.side = fold(2 - (int16_t)Yref);
    led(POS_PORT, POS_MASK, lyref.side, 1);
    led(NEG_PORT, NEG_MASK, lyref.side, 0);
    DELAY(pt, YREF_FLASH_TICKS);
    led(NEG_PORT, NEG_MASK, lyref.side, 1);
    led(POS_PORT, POS_MASK, lyref.side, 0);
    DELAY(pt, YREF_FLASH_TICKS);
    led(NEG_PORT, NEG_MASK, lyref.side, 0);
    PT_END(pt);
}

/* Show the orientation: LYref(0), YREF_SHOWS times (Ref, a localization report). */
static struct { pt_t pt; uint8_t k; } show;

static uint8_t co_show_yref(void)
{
    pt_t *pt = &show.pt;
    PT_BEGIN(pt);
    for (show.k = 0; show.k < YREF_SHOWS; show.k++) {
        PT_CALL(pt, co_lyref(YREF_KEEP));
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

static rotation_t led_rotation; /* LMCW..LSCCW sent by the PC */

/* --- relay to the control board ----------------------------------------------------- */
/* MSG(): '*' code a b c d '#' on UART0 (unused arguments 'N'), then wait for the echo:
 * any byte (thesis), the code itself (v2: else ACK_TIMEOUT when the wait is over). */
static struct {
    pt_t pt;
    uint8_t frame[RELAY_FRAME_LEN], result;
#if HEXBOT_V2
    uint8_t timed_out;
    uint16_t due;
#endif
} relay;

static uint8_t co_relay(uint8_t code, const uint8_t *a)
{
    pt_t *pt = &relay.pt;
    PT_BEGIN(pt);
    relay.frame[0] = BYTE_START;
    relay.frame[1] = code;
    for (uint8_t k = 0; k < 4; k++)
        relay.frame[2 + k] = k < fn_nargs(code) ? a[k] : ARG_UNUSED;
    if (code == FC_JxOpenAll || code == FC_JxCloseAll)
        relay.frame[2] = 0; /* these two send 0, not 'N', first (Appendix A) */
#if HEXBOT_V2
    if (code == FC_SelfTest)
        relay.frame[2] = switch_bits(); /* the control board reports them with the DIP id */
#endif
    relay.frame[6] = BYTE_END;
#if HEXBOT_V2
    /* an echo that came after its wait is stale: it would confirm the next relay of its code */
    while (board_rx_ready(UART0))
        (void)board_rx_read(UART0);
    TX(pt, UART0, relay.frame, RELAY_FRAME_LEN);
    relay.due = (uint16_t)(board_ticks() + ECHO_TIMEOUT_TICKS);
    do {
        RX_UNTIL(pt, UART0, relay.due, relay.result, relay.timed_out);
    } while (!relay.timed_out && relay.result != relay.frame[1]);
#else
    TX(pt, UART0, relay.frame, RELAY_FRAME_LEN);
    RX_TL(pt, UART0, ECHO_TIMEOUT_TICKS, relay.result);
#endif
    PT_END(pt);
}

/* A rotation on this module: relay `code` with (i, t1, t2, t3), then its LED mirror. */
static struct { pt_t pt; uint8_t code, args[4], ack; rotation_t mirror; } rotate;

static uint8_t co_rotate_mirror(void)
{
    return co_rotation(&rotate.mirror, rotation_steps(rotate.code), rotate.args[0], &rotate.args[1],
                       mirror_act);
}

static uint8_t co_rotate(uint8_t code, uint8_t i, uint8_t t1, uint8_t t2, uint8_t t3)
{
    pt_t *pt = &rotate.pt;
    PT_BEGIN(pt);
    rotate.code = code;
    rotate.args[0] = i, rotate.args[1] = t1, rotate.args[2] = t2, rotate.args[3] = t3;
    PT_CALL(pt, co_relay(rotate.code, rotate.args));
    rotate.ack = relay.result;
    if (!HEXBOT_V2 || rotate.ack == rotate.code) { /* v2 mirrors only what was confirmed */
        PT_CALL(pt, co_rotate_mirror());
    }
    PT_END(pt);
}

/* CW (67) / CCW (68): a mobile runs MCW/MCCW(mi..), a substrate SCW/SCCW(si..). */
static struct { pt_t pt; uint8_t ack; } turn;

static uint8_t co_turn(uint8_t code, const uint8_t *a)
{
    pt_t *pt = &turn.pt;
    PT_BEGIN(pt);
    turn.ack = ACK_UNKNOWN; /* C leaves it uninitialised when M = S = 0; we say 'N' */
    if (M == 1) {
        PT_CALL(pt, co_rotate(code == FC_CW ? FC_MCW : FC_MCCW, a[4], a[5], a[6], a[7]));
        turn.ack = rotate.ack;
    }
    if (S == 1) {
        PT_CALL(pt, co_rotate(code == FC_CW ? FC_SCW : FC_SCCW, a[0], a[1], a[2], a[3]));
        turn.ack = rotate.ack;
    }
    PT_END(pt);
}

/* --- localization ---------------------------------------------------------------- */
/* After a successful localization: "LOCALIZED", "Side: s", "Yref: y", show Yref. */
static struct { pt_t pt; } report;

static uint8_t co_report_localized(uint8_t side)
{
    pt_t *pt = &report.pt;
    PT_BEGIN(pt);
    IrSel(0);
    LINE_SEND(pt, line_pre());
    TX_P(pt, UART1, S_LOC);
    LINE_SEND(pt, line_report(S_SIDE, side));
    LINE_SEND(pt, line_report(S_YREF, Yref));
    PT_CALL(pt, co_show_yref());
    PT_END(pt);
}

static struct {
    pt_t pt;
    uint8_t w;               /* a sender's round or window, a listener's side */
    uint8_t side, k;         /* the side a sender is on; a count */
    uint8_t byte, heard;     /* the byte read; the side a MSG1 named (v2) */
    uint8_t body[MSG1_LEN];  /* the MSG1 read: '*', then body[1..7] */
#if HEXBOT_V2
    uint16_t t0;             /* the tick the step began on */
#endif
} localize;

#if !HEXBOT_V2
/* Appendix A's Localize(): a localized module sends fixed MSG1s on sides 2 and 3; a
 * listener takes X from the tens digit and Y from the units digit (spec section 12). */
static const uint8_t THESIS_MSG1[2][7] FW_CONST = {{0, 0, 0, 0, 0, 1, 5}, {0, 0, 1, 0, 0, 0, 6}};

/* '*' and the fixed MSG1 the thesis sends on side 2 or 3 */
static void line_thesis_msg1(uint8_t side)
{
    line_add(BYTE_START);
    line_add_P(THESIS_MSG1[side - 2], MSG1_LEN - 1);
}

static uint8_t co_localize(void)
{
    pt_t *pt = &localize.pt;
    PT_BEGIN(pt);
    if (L == 1) {
        for (localize.w = 0; localize.w < THESIS_LOCALIZE_ROUNDS; localize.w++) {
            for (localize.side = 2; localize.side <= 3; localize.side++) {
                led(POS_PORT, POS_MASK, localize.side, 1);
                led(NEG_PORT, NEG_MASK, localize.side, 1);
                IrSel(localize.side);
                for (localize.k = 0; localize.k < THESIS_LOCALIZE_REPEATS; localize.k++) {
                    DELAY(pt, THESIS_LOCALIZE_SEND_TICKS);
                    LINE_SEND(pt, line_pre()); /* two transmissions, as the thesis's two */
                    LINE_SEND(pt, line_thesis_msg1(localize.side));
                }
                led(POS_PORT, POS_MASK, localize.side, 0);
                led(NEG_PORT, NEG_MASK, localize.side, 0);
            }
        }
        IrSel(0);
        PT_EXIT(pt);
    }
    for (localize.w = 1; localize.w < 7; localize.w++) {
        IrSel(localize.w);
        led(POS_PORT, POS_MASK, localize.w, 1);
        led(NEG_PORT, NEG_MASK, localize.w, 1);
        do {
            RX_TL(pt, UART1, LOCALIZE_LISTEN_TICKS, localize.byte);
        } while (localize.byte != BYTE_START && localize.byte != ACK_TIMEOUT);
        if (localize.byte == BYTE_START) {
            for (localize.k = 1; localize.k < MSG1_LEN; localize.k++) {
                RX(pt, UART1, localize.body[localize.k]);
            }
            X = localize.body[2], Y = localize.body[6]; /* the firmware's digits (a defect) */
            Yref = (uint8_t)((((int16_t)localize.body[7] - localize.w) % 6 + 6) % 6);
            L = 1;
            localize.w = 7;
            IrSel(0);
            LOff();
        }
        /* after success localize.w is 7: side 1, as in C */
        led(POS_PORT, POS_MASK, localize.w, 0);
        led(NEG_PORT, NEG_MASK, localize.w, 0);
    }
    if (L == 1) {
        PT_CALL(pt, co_report_localized(localize.body[7]));
    } else {
        PT_CALL(pt, co_circle(LOCALIZE_FAILED_CIRCLE_ROUNDS, LOCALIZE_FAILED_CIRCLE_TICKS));
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

/* The tick window w (0..5) of this step begins on. */
static uint16_t window_start(uint8_t w)
{
    return (uint16_t)(localize.t0 + w * LOCALIZE_WINDOW_TICKS);
}

/* The tick the sender slot of body side 1..6 in window w begins on. */
static uint16_t slot_start(uint8_t w, uint8_t side)
{
    return (uint16_t)(window_start(w) + (side - 1) * LOCALIZE_SLOT_TICKS);
}

/* Ticks until the overflow that makes board_ticks() == target, at least 1. */
static uint16_t ticks_until(uint16_t target)
{
    int16_t n = (int16_t)(target - board_ticks());
    return n < 1 ? 1 : (uint16_t)n;
}

/* Whether MSG1, POS and Select mode 2 carry coordinate v: |v| <= COORD_LIMIT (bus/codec.py). */
static uint8_t carried(int16_t v)
{
    return v >= -COORD_LIMIT && v <= COORD_LIMIT;
}

/* MSG1 after '*' (body[1..7]): sign, tens (|v| div 10), units of X and of Y, then the side. */
static uint8_t msg1_valid(const uint8_t *body)
{
    return body[1] <= 1 && body[3] <= 9 && body[4] <= 1 && body[6] <= 9 && body[7] >= 1
        && body[7] <= 6 && 10 * body[2] + body[3] <= COORD_LIMIT && 10 * body[5] + body[6] <= COORD_LIMIT;
}

static int16_t msg1_coord(const uint8_t *p)
{
    int16_t v = (int16_t)(10 * p[1] + p[2]);
    return p[0] ? (int16_t)-v : v;
}

/* sign, tens, units: a coordinate in MSG1 (the caller checked carried(v)) */
static void line_coord(int16_t v)
{
    int16_t a = v < 0 ? -v : v;
    line_add(v < 0), line_add((uint8_t)(a / 10)), line_add((uint8_t)(a % 10));
}

/* The neighbour's cell across body side `side`: global side, X and Y. */
static uint8_t across(uint8_t side, int16_t *x, int16_t *y)
{
    uint8_t g = fold(side + Yref);
    *x = X + fw_sbyte(&NB_DX[g]), *y = Y + fw_sbyte(&NB_DY[g]);
    return g;
}

/* '*' MSG1 across body side `side`: the neighbour's cell there, and the side it faces us by */
static void line_msg1(uint8_t side)
{
    int16_t x, y;
    uint8_t g = across(side, &x, &y);
    line_add(BYTE_START);
    line_coord(x);
    line_coord(y);
    line_add(fold(g + 3));
}

/* A neighbour on body side `side` whose cell MSG1 carries (one beyond stays unlocalized). */
static uint8_t tellable(uint8_t side)
{
    int16_t x, y;
    across(side, &x, &y);
    return neighbour(side) && carried(x) && carried(y);
}

static uint8_t co_localize(void)
{
    pt_t *pt = &localize.pt;
    PT_BEGIN(pt);
    localize.t0 = board_ticks();
    if (L == 1) {
        for (localize.w = 0; localize.w < 6; localize.w++) {
            for (localize.side = 1; localize.side <= 6; localize.side++) {
                WAIT_TICK(pt, slot_start(localize.w, localize.side));
                if (!tellable(localize.side))
                    continue;
                IrSel(localize.side);
                DELAY(pt, LOCALIZE_MUX_SETTLE_TICKS);
                LINE_SEND(pt, line_pre()); /* preamble and role, then '*' MSG1 */
                LINE_SEND(pt, line_msg1(localize.side));
            }
        }
        WAIT_TICK(pt, (uint16_t)(localize.t0 + LOCALIZE_STEP_TICKS));
        IrSel(0);
        PT_EXIT(pt);
    }
    localize.heard = 0;
    for (localize.w = 1; localize.w <= 6; localize.w++) {
        if (!neighbour(localize.w))
            continue;
        WAIT_TICK(pt, window_start(localize.w - 1));
        IrSel(localize.w);
        do {
            RX_TL(pt, UART1, ticks_until(window_start(localize.w)), localize.byte);
        } while (localize.byte != BYTE_START && localize.byte != ACK_TIMEOUT);
        if (localize.byte != BYTE_START)
            continue;
        for (localize.k = 1; localize.k < MSG1_LEN; localize.k++) {
            RX_TL(pt, UART1, LOCALIZE_BYTE_TICKS, localize.body[localize.k]);
        }
        if (!msg1_valid(localize.body))
            continue;
        X = msg1_coord(&localize.body[1]), Y = msg1_coord(&localize.body[4]);
        Yref = (uint8_t)((((int16_t)localize.body[7] - localize.w) % 6 + 6) % 6);
        L = 1;
        localize.heard = localize.body[7];
        break;
    }
    IrSel(0);
    if (L && localize.heard && !v2_active) {
        PT_CALL(pt, co_report_localized(localize.heard)); /* v1 PCs see the thesis report lines */
    }
    PT_END(pt);
}
#endif

/* Ref(): become the reference module, then show the orientation. */
static struct { pt_t pt; } ref;

static uint8_t co_ref(void)
{
    pt_t *pt = &ref.pt;
    PT_BEGIN(pt);
    M = 0, S = 1, L = 1;
    X = Y = 0;
    Yref = 0;
    PT_CALL(pt, co_show_yref());
    PT_END(pt);
}

#if HEXBOT_V2
/* --- protocol v2: addressing, location report, addressed moves (docs/protocol.md) --- */
/* Report(): pre, "POS" id x+128 y+128 yref flags, EOL. */
static void line_position(void)
{
    line_pre();
    line_add3(TXT_POS);
    line_add(id);
    line_add((uint8_t)(X + COORD_OFFSET));
    line_add((uint8_t)(Y + COORD_OFFSET));
    line_add((uint8_t)(Yref % 6));
    line_add((uint8_t)((L ? 1 : 0) | (M ? 2 : 0) | (S ? 4 : 0)));
    line_eol();
}

/* Version(): pre, "VER" major minor profile, EOL. */
static void line_version(void)
{
    line_pre();
    line_add3(TXT_VER);
    line_add(FIRMWARE_VERSION_MAJOR), line_add(FIRMWARE_VERSION_MINOR);
    line_add(PROFILE_V2_BYTE);
    line_eol();
}

/* A command whose work is one line to the PC (Report, Version); the ACK follows it. */
static struct { pt_t pt; } send_line;

static uint8_t co_send_line(void (*build)(void))
{
    pt_t *pt = &send_line.pt;
    PT_BEGIN(pt);
    LINE_SEND(pt, build());
    PT_END(pt);
}

/* Whether `ident` names this module: id 0 ("no id": no DIP switch on, or no id byte at
 * boot) is never an address, or every module without one would answer at once. */
static uint8_t named(uint8_t ident)
{
    return ident != 0 && ident == id;
}

/* Select(mode, a, b): which modules obey the frames that follow. */
static void select_modules(uint8_t mode, uint8_t a, uint8_t b)
{
    v2_active = 1;
    if (mode == 0) {
        selected = 1, addressed = 0;
    } else if (mode == 1) {
        selected = addressed = named(a);
    } else if (mode == 2) {
        selected = addressed = L && X == (int16_t)a - COORD_OFFSET && Y == (int16_t)b - COORD_OFFSET;
    } else if (mode == 3) {
        if (named(a))
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
    if (!carried(X) || !carried(Y)) { /* beyond what POS reports: not localized, not wrapped */
        X = Y = 0, Yref = 0, L = 0;
        return;
    }
    Yref = (uint8_t)((Yref + (cw ? ORIENTATION_STEP_CW : 6 - ORIENTATION_STEP_CW)) % 6);
}

/* Move(dir, mid, mi, sid, si, t1, t2, t3): the two named modules act at once. */
static struct { pt_t pt; uint8_t cw, ack, has_ack; } move;

static uint8_t co_move(const uint8_t *a)
{
    pt_t *pt = &move.pt;
    PT_BEGIN(pt);
    move.cw = a[0] == 1; /* dir: 1 CW, 2 CCW */
    move.has_ack = 1;
    if (named(a[1])) {
        PT_CALL(pt, co_rotate(move.cw ? FC_MCW : FC_MCCW, a[2], a[5], a[6], a[7]));
        move.ack = rotate.ack;
        if (L && (move.ack == FC_MCW || move.ack == FC_MCCW))
            moved(a[2], move.cw);
    } else if (named(a[3])) {
        substrate_turn = 1;
        PT_CALL(pt, co_rotate(move.cw ? FC_SCW : FC_SCCW, a[4], a[5], a[6], a[7]));
        move.ack = rotate.ack;
    } else {
        move.has_ack = 0;
    }
    PT_END(pt);
}

/* --- v2 distributed reconfiguration: a Walter round (docs/protocol.md) ----------------- */
/* Figure 10 as module_sim/walter.py runs it, and CommBoard.WalterBeat's round. Sides are
 * global (body side + Yref); contacts is a bit mask, bit s-1 = a neighbour across side s. */
static const uint8_t WALTER_T[3] = WALTER_ROTATION_TICKS;
static const uint8_t BUSY[1] = {BYTE_WALTER_BUSY};

static struct {
    uint8_t on, n, plen, cost;
    int16_t ax, ay;                           /* the anchor: where I meets G */
    uint8_t goal[WALTER_TABLE_CAPACITY][3];   /* per position: x+128, y+128, mode (0, 0: none) */
    uint8_t started;
    int16_t sx, sy;                           /* its cell when the first round began */
    uint8_t position;                         /* WALTER_NO_POSITION until free */
    uint8_t passed_cw, passed_ccw, passed_by[32]; /* bit p: the mover at position p passed */
    uint8_t free, delay, stopped, moved, unanswered;
    uint8_t has_pivot;
    int16_t px, py;                           /* the contact it last turned about */
    uint8_t plan, cw, joint, sub, holders;    /* this round's move: pivot joint, substrate side */
} walter;

static uint8_t walter_entry(void)
{
    uint8_t p = walter.position;
    return p < WALTER_TABLE_CAPACITY && (walter.goal[p][0] || walter.goal[p][1]);
}

static uint8_t walter_at_goal(int16_t x, int16_t y)
{
    const uint8_t *e = walter.goal[walter.position];
    return x == (int16_t)e[0] - COORD_OFFSET && y == (int16_t)e[1] - COORD_OFFSET;
}

static uint8_t walter_is_anchor(void)
{
    return walter.started && walter.sx == walter.ax && walter.sy == walter.ay;
}

static uint8_t walter_done(void)
{
    return walter.stopped || walter_is_anchor();
}

static uint8_t has(uint8_t mask, uint8_t side)
{
    return mask >> (side - 1) & 1;
}

static uint8_t flips(uint8_t c)
{
    uint8_t f = 0;
    for (uint8_t i = 0; i < 6; i++)
        f += (uint8_t)((c >> i & 1) != (c >> ((i + 1) % 6) & 1));
    return f;
}

static uint8_t touching(uint8_t c)
{
    uint8_t k = 0;
    for (uint8_t i = 0; i < 6; i++)
        k += c >> i & 1;
    return k;
}

/* The global side of the start cell that points away from the anchor along I, or 0. */
static uint8_t walter_beyond(void)
{
    if (!walter.started || walter_is_anchor())
        return 0;
    for (uint8_t s = 1; s <= 6; s++) {
        int16_t x = walter.ax, y = walter.ay;
        for (uint8_t k = 0; k < walter.n; k++) {
            x += fw_sbyte(&NB_DX[s]), y += fw_sbyte(&NB_DY[s]);
            if (x == walter.sx && y == walter.sy)
                return s;
        }
    }
    return 0;
}

/* One step round the structure from the side towards the contact it last turned about. */
static uint8_t walter_plan(uint8_t c, uint8_t cw, uint8_t pivot)
{
    if (!has(c, pivot))
        return 0;
    uint8_t s = pivot;
    for (uint8_t k = 0; k < 6; k++) {
        uint8_t next = fold((int16_t)s + (cw ? -1 : 1));
        if (!has(c, next)) {
            walter.cw = cw, walter.sub = s;
            walter.joint = cw ? s : fold((int16_t)s + 1);
            walter.holders = (uint8_t)(c & ~(1u << (s - 1)));
            return 1;
        }
        s = next;
    }
    return 0;
}

/* Figure 10 for this round from its cell and contacts: walter.plan says whether it moves. */
static void walter_decide(uint8_t c)
{
    walter.moved = walter.unanswered = walter.plan = 0;
    if (!walter.started)
        walter.started = 1, walter.sx = X, walter.sy = Y;
    if (walter_is_anchor() || walter.stopped)
        return;
    if (walter_entry() && walter_at_goal(X, Y)) {
        walter.stopped = 1; /* once stopped in its goal, it never leaves */
        return;
    }
    if (!walter.free) {
        uint8_t beyond = walter_beyond();
        if (beyond && X == walter.sx && Y == walter.sy && has(c, beyond))
            return;
        if (flips(c) != 2 || touching(c) >= 5)
            return;
        walter.free = 1;
        walter.position = (uint8_t)(walter.passed_cw + walter.passed_ccw);
        walter.has_pivot = beyond != 0;
        if (beyond) {
            uint8_t t = fold((int16_t)beyond + 3);
            walter.px = X + fw_sbyte(&NB_DX[t]), walter.py = Y + fw_sbyte(&NB_DY[t]);
        }
        if (!walter_entry())
            return;
        walter.delay = walter.goal[walter.position][2] >> WALTER_MODE_DELAY_SHIFT & WALTER_MODE_DELAY_MAX;
    }
    if (!walter_entry() || !walter.has_pivot)
        return;
    if (walter.delay > 0) {
        walter.delay--;
        return;
    }
    uint8_t towards = 0;
    for (uint8_t s = 1; s <= 6; s++)
        if (X + fw_sbyte(&NB_DX[s]) == walter.px && Y + fw_sbyte(&NB_DY[s]) == walter.py)
            towards = s;
    if (!towards || !has(c, towards)) {
        /* the contact it last turned about has gone: any side of its one arc will do */
        towards = 0;
        for (uint8_t s = 6; s >= 1 && flips(c) == 2; s--)
            if (has(c, s))
                towards = s;
    }
    if (towards)
        walter.plan = walter_plan(c, walter.goal[walter.position][2] & WALTER_MODE_CW, towards);
}

/* The mover at position `who` asks this module anything (pivot or hold): it passes, so count
 * it once while in I; a hold's sense is the mover's table entry's (module_sim/walter.py). */
static void walter_passed(uint8_t op, uint8_t who)
{
    if (walter.free || walter_done() || walter.passed_by[who >> 3] >> (who & 7) & 1)
        return;
    walter.passed_by[who >> 3] |= (uint8_t)(1u << (who & 7));
    uint8_t cw = op == WALTER_OP_PIVOT_CW;
    if (op == WALTER_OP_HOLD && who < WALTER_TABLE_CAPACITY)
        cw = walter.goal[who][2] & WALTER_MODE_CW;
    if (cw)
        walter.passed_cw++;
    else
        walter.passed_ccw++;
}

static uint8_t walter_flags(void)
{
    uint8_t f = 0;
    if (walter.free) f |= WALTER_FLAG_FREE;
    if (walter.moved) f |= WALTER_FLAG_MOVED;
    if (walter_entry() && (walter.goal[walter.position][2] & WALTER_MODE_CW)) f |= WALTER_FLAG_CW;
    if (walter.stopped) f |= WALTER_FLAG_STOPPED;
    if (walter_is_anchor()) f |= WALTER_FLAG_ANCHOR;
    if (walter.unanswered) f |= WALTER_FLAG_UNANSWERED;
    return f;
}

/* WalterSetup(n, plen, cost, ax, ay): a new problem. */
static void walter_setup(const uint8_t *a)
{
    memset(&walter, 0, sizeof walter);
    walter.on = 1, walter.n = a[0], walter.plen = a[1], walter.cost = a[2];
    walter.ax = (int16_t)a[3] - COORD_OFFSET, walter.ay = (int16_t)a[4] - COORD_OFFSET;
    walter.position = WALTER_NO_POSITION;
}

/* WalterGoal(k, x, y, m, x2, y2, m2): entries k and k+1 (x = y = 0 on the wire: none). */
static void walter_goal(const uint8_t *a)
{
    if (!walter.on)
        return;
    for (uint8_t j = 0; j < 2; j++) {
        uint16_t at = (uint16_t)(a[0] + j);
        const uint8_t *e = &a[1 + 3 * j];
        if ((e[0] || e[1]) && at < WALTER_TABLE_CAPACITY)
            walter.goal[at][0] = e[0], walter.goal[at][1] = e[1], walter.goal[at][2] = e[2];
    }
}

/* "W" op ~op position, or "w" op ~op: a side message (one burst). */
static void line_walter(uint8_t tag, uint8_t op, uint8_t who, uint8_t with_who)
{
    line_add(tag), line_add(op), line_add((uint8_t)~op);
    if (with_who)
        line_add(who);
}

/* Wait until tick `end` for a side message starting with `tag` (a request: op, ~op, the
 * mover's position; an answer: op, ~op); wside.op (0: none) and wside.body[2]. */
static struct { pt_t pt; uint8_t byte, k, n, body[WALTER_REQUEST_LEN - 1], op; } wside;

static uint8_t co_walter_side(uint8_t tag, uint16_t end)
{
    pt_t *pt = &wside.pt;
    PT_BEGIN(pt);
    wside.op = 0;
    wside.n = tag == BYTE_WALTER_REQUEST ? WALTER_REQUEST_LEN - 1 : WALTER_ANSWER_LEN - 1;
    do {
        RX_TL(pt, UART1, ticks_until(end), wside.byte);
    } while (wside.byte != tag && wside.byte != ACK_TIMEOUT);
    if (wside.byte != tag)
        PT_EXIT(pt);
    for (wside.k = 0; wside.k < wside.n; wside.k++) {
        RX_TL(pt, UART1, ticks_until(end), wside.body[wside.k]);
    }
    if ((uint8_t)(wside.body[0] ^ wside.body[1]) == 0xFF && wside.body[0] >= WALTER_OP_HOLD
        && wside.body[0] <= WALTER_OP_LATE)
        wside.op = wside.body[0];
    PT_END(pt);
}

/* A control-board code this board sends itself, with its LED mirror (as co_dispatch). */
static rotation_two_t led_two;
static struct { pt_t pt; uint8_t code, args[4]; } mirrored;

/* The arguments of the next co_relay_mirrored. */
static void mirrored_args(uint8_t a, uint8_t b, uint8_t c)
{
    mirrored.args[0] = a, mirrored.args[1] = b, mirrored.args[2] = c;
}

static uint8_t co_relay_mirrored(uint8_t code)
{
    pt_t *pt = &mirrored.pt;
    PT_BEGIN(pt);
    mirrored.code = code;
    PT_CALL(pt, co_relay(mirrored.code, mirrored.args));
    if (mirrored.code == FC_JxOpen) {
        led(JNT_PORT, JNT_MASK, mirrored.args[0], 1);
    } else if (mirrored.code == FC_JxCloseAll) {
        leds(JNT_PORT, JNT_MASK, 0);
    } else {
        PT_CALL(pt, co_rotation_two(&led_two, mirrored.args[0], &mirrored.args[1], WALTER_T, mirror_act));
    }
    PT_END(pt);
}

/* Two movers may turn about one substrate only from sides that do not meet at a joint. */
static uint8_t walter_apart(uint8_t first, uint8_t second)
{
    uint8_t d = (uint8_t)((second + 6 - first) % 6);
    return d != 0 && d != 1 && d != 5;
}

/* WalterBeat(r_hi, r_lo): one round (docs/protocol.md). */
static struct {
    pt_t pt;
    uint16_t t0, round;
    uint16_t end; /* the tick this window ends on */
    uint8_t c, g, op, answered, late, opened, npivots, pivot_op[2], pivot_g[2], args[4], dirs, k;
} wround;

static uint16_t wround_at(uint16_t ticks)
{
    return (uint16_t)(wround.t0 + ticks);
}

/* The tick window g (1..6) of this round starts on; its end is window g + 1's start. */
static uint16_t window_at(uint8_t g)
{
    return wround_at((uint16_t)((g - 1) * WALTER_WINDOW_TICKS));
}

static uint8_t co_walter(const uint8_t *a)
{
    pt_t *pt = &wround.pt;
    PT_BEGIN(pt);
    wround.round = (uint16_t)(a[0] << 8 | a[1]);
    if (wround.round == 0)
        walter.on = 0;
    if (!walter.on || wround.round == 0 || !L)
        PT_EXIT(pt);
    wround.t0 = board_ticks();
    wround.c = 0;
    for (uint8_t s = 1; s <= 6; s++)
        if (neighbour(s))
            wround.c |= (uint8_t)(1u << (fold((int16_t)s + Yref) - 1));
    walter_decide(wround.c);
    wround.answered = 1, wround.late = 0, wround.opened = 0, wround.npivots = 0;
    for (wround.g = 1; wround.g <= 6; wround.g++) {
        wround.op = 0;
        if (walter.plan && wround.answered) {
            if (wround.g == walter.sub)
                wround.op = walter.cw ? WALTER_OP_PIVOT_CW : WALTER_OP_PIVOT_CCW;
            else if (has(walter.holders, wround.g))
                wround.op = WALTER_OP_HOLD;
        }
        if (wround.op) { /* ask the neighbour across global side g */
            wround.end = window_at(wround.g + 1);
            WAIT_TICK(pt, window_at(wround.g));
            IrSel(fold((int16_t)wround.g - Yref));
            WAIT_TICK(pt, (uint16_t)(window_at(wround.g) + WALTER_MUX_SETTLE_TICKS));
            LINE_SEND(pt, line_walter(BYTE_WALTER_REQUEST, wround.op, walter.position, 1));
            PT_CALL(pt, co_walter_side(BYTE_WALTER_ANSWER, wround.end));
            if (wround.op != WALTER_OP_HOLD && wside.op == WALTER_OP_LATE) {
                wround.late = 1;
            } else if (wside.op != wround.op) {
                wround.answered = 0;
            } else if (wround.op == WALTER_OP_HOLD) { /* and open its own pin on that side */
                mirrored_args(fold((int16_t)wround.g + 1 - Yref), 0, 0);
                PT_CALL(pt, co_relay_mirrored(FC_JxOpen));
                wround.opened = 1;
            }
            continue;
        }
        /* listen for a mover across global side g + 3 (it sends on its side g) */
        if (!has(wround.c, fold((int16_t)wround.g + 3)))
            continue;
        wround.end = window_at(wround.g + 1);
        WAIT_TICK(pt, window_at(wround.g));
        IrSel(fold((int16_t)wround.g + 3 - Yref));
        PT_CALL(pt, co_walter_side(BYTE_WALTER_REQUEST, wround.end));
        if (!wside.op)
            continue;
        if (walter.plan && wside.op != WALTER_OP_HOLD)
            continue; /* a mover is nobody's substrate (it opens its own pin to a mover) */
        if (wside.op == WALTER_OP_LATE || (wside.op != WALTER_OP_HOLD && wround.npivots == 2))
            continue; /* a substrate turns two movers at most */
        /* a second mover beside the first: its turn comes late, after the first's (their two
         * repelling sides on together would be a drive pair of this module's own) */
        wround.op = wside.op != WALTER_OP_HOLD && wround.npivots && !walter_apart(wround.pivot_g[0], wround.g)
                        ? WALTER_OP_LATE : wside.op;
        LINE_SEND(pt, line_walter(BYTE_WALTER_ANSWER, wround.op, 0, 0));
        walter_passed(wside.op, wside.body[2]);
        if (wside.op == WALTER_OP_HOLD) { /* the pin at the end of the side facing the mover */
            mirrored_args(fold((int16_t)wround.g + 4 - Yref), 0, 0);
            PT_CALL(pt, co_relay_mirrored(FC_JxOpen));
            wround.opened = 1;
        } else {
            wround.pivot_op[wround.npivots] = wside.op, wround.pivot_g[wround.npivots] = wround.g;
            wround.npivots++;
        }
    }
    /* back to the centre when the windows are over: an answer's last byte is still on the
     * wire when the program moves on (the multiplexer would cut it) */
    WAIT_TICK(pt, window_at(7));
    IrSel(0);
    walter.unanswered = walter.plan && !wround.answered;
    WAIT_TICK(pt, wround_at(WALTER_ACTUATION_AT));
    if (walter.plan && wround.answered) {
        if (wround.late) {
            WAIT_TICK(pt, wround_at(WALTER_LATE_AT));
        }
        wround.args[0] = fold((int16_t)walter.joint - Yref);
        PT_CALL(pt, co_rotate(walter.cw ? FC_MCW : FC_MCCW, wround.args[0], WALTER_T[0], WALTER_T[1], WALTER_T[2]));
        walter.px = X + fw_sbyte(&NB_DX[walter.sub]), walter.py = Y + fw_sbyte(&NB_DY[walter.sub]);
        walter.moved = 1;
        moved(wround.args[0], walter.cw);
    } else if (wround.npivots) {
        /* the pivot in this body: the mover's joint (g for CW, g + 1 for CCW) - Yref */
        for (uint8_t k = 0; k < wround.npivots; k++)
            wround.args[k] = fold((int16_t)wround.pivot_g[k] + (wround.pivot_op[k] == WALTER_OP_PIVOT_CW ? 0 : 1) - Yref);
        if (wround.npivots == 1 || !walter_apart(wround.pivot_g[0], wround.pivot_g[1])) {
            for (wround.k = 0; wround.k < wround.npivots; wround.k++) { /* the second: the late slot */
                if (wround.k) {
                    WAIT_TICK(pt, wround_at(WALTER_LATE_AT));
                }
                PT_CALL(pt, co_rotate(wround.pivot_op[wround.k] == WALTER_OP_PIVOT_CW ? FC_SCW : FC_SCCW,
                                      wround.args[wround.k], WALTER_T[0], WALTER_T[1], WALTER_T[2]));
            }
        } else {
            wround.dirs = (uint8_t)((wround.pivot_op[0] == WALTER_OP_PIVOT_CW)
                                    | (wround.pivot_op[1] == WALTER_OP_PIVOT_CW) << 1);
            mirrored_args(wround.dirs, wround.args[0], wround.args[1]);
            PT_CALL(pt, co_relay_mirrored(FC_STwo));
        }
    } else if (wround.opened) { /* a rotation ends with every joint closed; a holder closes them itself */
        WAIT_TICK(pt, wround_at(WALTER_HOLD_END_AT));
        mirrored_args(0, 0, 0);
        PT_CALL(pt, co_relay_mirrored(FC_JxCloseAll));
    }
    WAIT_TICK(pt, wround_at(WALTER_LOG_AT));
    if (walter.free && walter_entry() && walter_at_goal(X, Y))
        walter.stopped = 1;
    wround.args[0] = (uint8_t)wround.round, wround.args[1] = walter_flags();
    wround.args[2] = walter.position, wround.args[3] = walter.delay;
    PT_CALL(pt, co_relay(FC_WalterLog, wround.args));
    WAIT_TICK(pt, wround_at(WALTER_BUSY_AT));
    if (!walter_done()) {
        TX(pt, UART1, BUSY, 1);
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
    case FC_LYref: return co_lyref(a[0]);
    case FC_LMCW: case FC_LMCCW: case FC_LSCW: case FC_LSCCW:
        return co_rotation(&led_rotation, rotation_steps(code), a[0], &a[1], mirror_act);
    case FC_Ref: return co_ref();
    case FC_Localize: return co_localize();
    case FC_CW: case FC_CCW: return co_turn(code, a);
#if HEXBOT_V2
    case FC_Report: return co_send_line(line_position);
    case FC_Version: return co_send_line(line_version);
    case FC_WalterSetup: walter_setup(a); return PT_DONE;
    case FC_WalterGoal: walter_goal(a); return PT_DONE;
    case FC_WalterBeat: return co_walter(a);
    case FC_LSTwo: return co_rotation_two(&led_two, a[0], &a[1], WALTER_T, mirror_act);
#endif
    default: return PT_DONE;
    }
}

/* Run frame[] and decide the ACK byte (has_ack = 0: stay silent). */
static struct { pt_t pt; uint8_t board, ack, has_ack, k, mirror; } dispatch;

static uint8_t co_dispatch(void)
{
    pt_t *pt = &dispatch.pt;
    PT_BEGIN(pt);
    dispatch.has_ack = 1;
    dispatch.board = fn_board(frame[0]);
#if HEXBOT_V2
    if (frame[0] == FC_Select) {
        select_modules(frame[1], frame[2], frame[3]);
        dispatch.ack = frame[0];
        dispatch.has_ack = addressed;
        PT_EXIT(pt);
    }
    if (frame[0] == FC_Move) {
        PT_CALL(pt, co_move(&frame[1]));
        dispatch.ack = move.ack, dispatch.has_ack = move.has_ack;
        PT_EXIT(pt);
    }
    if (!selected) {
        dispatch.has_ack = 0;
        PT_EXIT(pt);
    }
#else
    if (fn_is_v2(frame[0]))
        dispatch.board = BOARD_NONE; /* a thesis module does not know our codes */
#endif
    if (dispatch.board == BOARD_CONTROL) {
        PT_CALL(pt, co_relay(frame[0], &frame[1]));
        dispatch.ack = relay.result;
        /* v2 mirrors only what the control board confirmed: the LEDs would show a coil off */
        for (dispatch.k = HEXBOT_V2 && dispatch.ack != frame[0] ? 2 : 0; dispatch.k < 2; dispatch.k++) {
            dispatch.mirror = fn_mirror(frame[0], dispatch.k); /* looked up once, not every step */
            PT_CALL(pt, run_comm(dispatch.mirror, &frame[1]));
        }
    } else if (dispatch.board == BOARD_COMM) {
        PT_CALL(pt, run_comm(frame[0], &frame[1]));
        dispatch.ack = frame[0] == FC_CW || frame[0] == FC_CCW ? turn.ack : frame[0];
    } else {
        dispatch.ack = ACK_UNKNOWN;
    }
#if HEXBOT_V2
    if (v2_active && !addressed)
        dispatch.has_ack = 0; /* a broadcast: answers would collide on the centre channel */
#endif
    PT_END(pt);
}

#if HEXBOT_V2
/* The frame did not end in '#': it was garbage with a '*' in it. Keep what follows the
 * first '*' among frame[1..8] and the byte read in place of '#'; 0xFF if there is none. */
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

static struct {
    pt_t pt;
    uint8_t byte, n;
#if HEXBOT_V2
    uint8_t timed_out;
#endif
} listen;

static uint8_t co_listen(void)
{
    pt_t *pt = &listen.pt;
    PT_BEGIN(pt);
    do {
        RX(pt, UART1, listen.byte);
    } while (listen.byte != BYTE_START);
#if HEXBOT_V2
    /* v2 reads the '#' too (module_sim/framing.py): each byte within FRAME_BYTE_TICKS, a
     * silence ends the frame unread; one without its '#' resynchronises on a '*' inside it */
    for (listen.n = 0; listen.n < PC_FRAME_LEN - 1;) {
        RX_TL2(pt, UART1, FRAME_BYTE_TICKS, frame[listen.n], listen.timed_out);
        if (listen.timed_out)
            PT_EXIT(pt);
        if (++listen.n == PC_FRAME_LEN - 1 && frame[PC_FRAME_LEN - 2] != BYTE_END) {
            listen.n = resync();
            if (listen.n == 0xFF)
                PT_EXIT(pt);
        }
    }
#else
    for (listen.n = 0; listen.n < 9; listen.n++) {
        RX(pt, UART1, frame[listen.n]);
    }
#endif
    substrate_turn = 0;
    PT_CALL(pt, co_dispatch());
    if (!dispatch.has_ack)
        PT_EXIT(pt);
    if (S || substrate_turn) {
        DELAY(pt, SUBSTRATE_ACK_DELAY_TICKS); /* let the mobile module answer first */
    }
    LINE_SEND(pt, line_ack(dispatch.ack));
    PT_END(pt);
}

/* --- the program: main() of Appendix A -------------------------------------------------- */
static struct {
    pt_t pt;
    uint8_t byte; /* a handshake byte read, or the one to send */
#if HEXBOT_V2
    uint8_t timed_out;
#endif
} program;

static uint8_t co_program(void)
{
    pt_t *pt = &program.pt;
    PT_BEGIN(pt);
    LOff();
    IrSel(0);
    LINE_SEND(pt, line_pre());
    TX_P(pt, UART1, S_COMM_READY);
    do {
        RX(pt, UART0, program.byte);
    } while (program.byte != BYTE_READY);
    PT_CALL(pt, co_flash(FC_LFlash1, BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS));
    TX_P(pt, UART1, S_CTR_READY);
    program.byte = BYTE_READY;
    TX(pt, UART0, &program.byte, 1);
    for (;;) {
        RX_TL(pt, UART0, HANDSHAKE_RETRY_TICKS, program.byte);
        if (program.byte == BYTE_LISTENING)
            break;
        program.byte = BYTE_READY;
        TX(pt, UART0, &program.byte, 1);
    }
#if HEXBOT_V2
    /* the control board's DIP switches: any byte is an id, '~' (126) too; silence is none */
    RX_TL2(pt, UART0, HANDSHAKE_RETRY_TICKS, program.byte, program.timed_out);
    id = program.timed_out ? 0 : program.byte;
#endif
    PT_CALL(pt, co_flash(FC_LFlash2, BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS));
    TX_P(pt, UART1, S_CTR_LST);
    PT_CALL(pt, co_circle(BOOT_CIRCLE_ROUNDS, BOOT_CIRCLE_TICKS));
#if !HEXBOT_V2
    Yref = 1; /* the thesis assumed its test orientation instead of localizing */
#endif
    IrSel(0);
    TX_P(pt, UART1, S_LOC); /* v2 keeps the banner for v1 PCs; it no longer claims L = 1 */
    IrSel(0);
    PT_CALL(pt, co_flash(FC_LColor, BOOT_FLASH_ROUNDS, BOOT_FLASH_TICKS));
    TX_P(pt, UART1, S_COMM_LST);
    for (;;) {
        PT_CALL(pt, co_listen());
    }
    PT_END(pt);
}

void program_step(void)
{
    co_program();
}

/* The control board: joint solenoids and side magnets (Table 3-3), the comm board on
 * UART0, a PC terminal on UART1 (the debug link). Behaviour: spec sections 5 and 6,
 * module_sim/control_board.py is the reference model. */
#include "hexbot.h"

const uint8_t program_outputs[5] = {CONTROL_OUTPUTS_A, CONTROL_OUTPUTS_B, CONTROL_OUTPUTS_C,
                                    CONTROL_OUTPUTS_D, CONTROL_OUTPUTS_E};
const uint8_t program_pullups[5] = {CONTROL_PULLUPS_A, CONTROL_PULLUPS_B, CONTROL_PULLUPS_C,
                                    CONTROL_PULLUPS_D, CONTROL_PULLUPS_E};

static const uint8_t JOINT_PORT[7] FW_CONST = JOINT_PORTS;
static const uint8_t JOINT_MASK[7] FW_CONST = JOINT_MASKS;
static const uint8_t POS_PORT[7] FW_CONST = MAGNET_POS_PORTS;
static const uint8_t POS_MASK[7] FW_CONST = MAGNET_POS_MASKS;
static const uint8_t NEG_PORT[7] FW_CONST = MAGNET_NEG_PORTS;
static const uint8_t NEG_MASK[7] FW_CONST = MAGNET_NEG_MASKS;
static const uint8_t ACTUATOR_BITS[5] = {CONTROL_OUTPUTS_A, CONTROL_OUTPUTS_B, CONTROL_OUTPUTS_C,
                                         CONTROL_OUTPUTS_D, CONTROL_OUTPUTS_E};
static const uint8_t UART_PINS[5] = {CONTROL_UART_PINS_A, CONTROL_UART_PINS_B, CONTROL_UART_PINS_C,
                                     CONTROL_UART_PINS_D, CONTROL_UART_PINS_E};

static const char S_PREAMBLE[] FW_CONST = TXT_PREAMBLE;
static const char S_CTR_READY[] FW_CONST = TXT_CTR_READY;
static const char S_COMM_READY[] FW_CONST = TXT_COMM_READY;
static const char S_CTR_LST[] FW_CONST = TXT_CTR_LST;

/* v2 actuator reports (docs/protocol.md): once the board listens, every step that changes
 * a solenoid or relay sends one ACT line in the background. */
static uint8_t reporting, reported[3], have_reported;

#if HEXBOT_V2
/* The DIP switches: an ON switch pulls its pin low against the pull-up (bus/pins.py). */
static uint8_t dip_id(void)
{
    uint8_t levels = board_pins(DIP_PORT);
    return DIP_ACTIVE_LOW ? (uint8_t)~levels : levels;
}
#endif

static void JxOpen(int16_t i) { pin_change(JOINT_PORT, JOINT_MASK, i, 1); }
static void JxClose(int16_t i) { pin_change(JOINT_PORT, JOINT_MASK, i, 0); }
static void SxP(int16_t i) { pin_change(POS_PORT, POS_MASK, i, 1); }
static void SxN(int16_t i) { pin_change(NEG_PORT, NEG_MASK, i, 1); }

static void SxOff(int16_t i)
{
    pin_change(POS_PORT, POS_MASK, i, 0);
    pin_change(NEG_PORT, NEG_MASK, i, 0);
}

/* all six joints: one write per port, as the thesis's PORTA mask did */
static void JxAll(uint8_t on) { pins_change(JOINT_PORT, JOINT_MASK, on); }

static void SxOffAll(void)
{
    /* PORTB and PORTD hold every relay; keep only the UART pins */
    board_port_write(PORT_B, board_port(PORT_B) & UART_PINS[PORT_B]);
    board_port_write(PORT_D, board_port(PORT_D) & UART_PINS[PORT_D]);
}

static void TurnOffAll(void)
{
    SxOffAll();
    JxAll(0);
}

static void rotation_act(uint8_t op, int16_t i)
{
    switch (op) {
    case ROT_OPEN: JxOpen(i); break;
    case ROT_POS: SxP(i); break;
    case ROT_NEG: SxN(i); break;
    case ROT_CLOSE_ALL: JxAll(0); break;
    default: SxOffAll(); break;
    }
}

/* JTest, SPTest, SNTest: n rounds, each of the six on for t ticks, off for t ticks. */
static pt_t pt_test;
static uint8_t test_round, test_k;

static uint8_t co_test(uint8_t code, uint8_t n, uint8_t t)
{
    pt_t *pt = &pt_test;
    PT_BEGIN(pt);
    for (test_round = 0; test_round < n; test_round++) {
        for (test_k = 1; test_k <= 6; test_k++) {
            if (code == FC_JTest)
                JxOpen(test_k);
            else if (code == FC_SPTest)
                SxP(test_k);
            else
                SxN(test_k);
            DELAY(pt, t);
            if (code == FC_JTest)
                JxClose(test_k);
            else
                SxOff(test_k);
            DELAY(pt, t);
        }
    }
    PT_END(pt);
}

#if HEXBOT_V2
/* SelfTest(switches): each solenoid, then each magnet positive, then negative, on for a pulse
 * and off as long (the ACT reports show each); then "TST" id switches on the debug UART. */
static pt_t pt_selftest;
static uint8_t st_k;
static uint8_t st_line[7];

static void selftest_coil(uint8_t k, uint8_t on)
{
    const uint8_t *ports = k < 6 ? JOINT_PORT : k < 12 ? POS_PORT : NEG_PORT;
    const uint8_t *masks = k < 6 ? JOINT_MASK : k < 12 ? POS_MASK : NEG_MASK;
    pin_change(ports, masks, (int16_t)(k % 6 + 1), on);
}

static uint8_t co_selftest(uint8_t switches)
{
    pt_t *pt = &pt_selftest;
    PT_BEGIN(pt);
    for (st_k = 0; st_k < 18; st_k++) {
        selftest_coil(st_k, 1);
        DELAY(pt, SELFTEST_PULSE_TICKS);
        selftest_coil(st_k, 0);
        DELAY(pt, SELFTEST_PULSE_TICKS);
    }
    st_line[0] = TXT_TST[0], st_line[1] = TXT_TST[1], st_line[2] = TXT_TST[2];
    st_line[3] = dip_id(), st_line[4] = switches, st_line[5] = TXT_EOL[0], st_line[6] = TXT_EOL[1];
    TX(pt, UART1, st_line, 7);
    PT_END(pt);
}
#endif

static rotation_t rotation;
#if HEXBOT_V2
static rotation_two_t rotation_two;
static const uint8_t WALTER_T[3] = WALTER_ROTATION_TICKS;

/* WalterLog(round, flags, position, delay): the round's line, "WLK" and the four bytes. */
static pt_t pt_wlk;
static uint8_t wlk_line[9];

static uint8_t co_walter_log(const uint8_t *a)
{
    pt_t *pt = &pt_wlk;
    PT_BEGIN(pt);
    wlk_line[0] = TXT_WLK[0], wlk_line[1] = TXT_WLK[1], wlk_line[2] = TXT_WLK[2];
    for (uint8_t j = 0; j < 4; j++)
        wlk_line[3 + j] = a[j];
    wlk_line[7] = TXT_EOL[0], wlk_line[8] = TXT_EOL[1];
    TX(pt, UART1, wlk_line, 9);
    PT_END(pt);
}
#endif

/* Run code with its arguments; PT_DONE when finished (at once for the instant ones). */
static uint8_t execute(uint8_t code, const uint8_t *a)
{
    switch (code) {
    case FC_JxOpen: JxOpen(a[0]); return PT_DONE;
    case FC_JxClose: JxClose(a[0]); return PT_DONE;
    case FC_JxOpenAll: JxAll(1); return PT_DONE;
    case FC_JxCloseAll: JxAll(0); return PT_DONE;
    case FC_SxP: SxP(a[0]); return PT_DONE;
    case FC_SxN: SxN(a[0]); return PT_DONE;
    case FC_SxOff: SxOff(a[0]); return PT_DONE;
    case FC_SxOffAll: SxOffAll(); return PT_DONE;
    case FC_TurnOffAll: TurnOffAll(); return PT_DONE;
    case FC_JTest: case FC_SPTest: case FC_SNTest: return co_test(code, a[0], a[1]);
    case FC_MCW: case FC_MCCW: case FC_SCW: case FC_SCCW:
        return co_rotation(&rotation, rotation_steps(code), a[0], &a[1], rotation_act);
#if HEXBOT_V2
    case FC_SelfTest: return co_selftest(a[0]);
    case FC_WalterLog: return co_walter_log(a);
    case FC_STwo: return co_rotation_two(&rotation_two, a[0], &a[1], WALTER_T, rotation_act);
#endif
    default: return PT_DONE; /* the thesis's if-chain matches nothing */
    }
}

static pt_t pt_main;
static uint8_t byte, msg[5], k;
#if HEXBOT_V2
static uint8_t timed_out;
#endif
static uint8_t line[10]; /* "ACK" c EOL, or "MSG" 5 bytes EOL */

static uint8_t co_main(void)
{
    pt_t *pt = &pt_main;
    PT_BEGIN(pt);
    DELAY(pt, BOOT_SETTLE_TICKS); /* let the supplies settle */
    TurnOffAll();
    PT_CALL(pt, co_test(FC_JTest, BOOT_JTEST_ROUNDS, BOOT_JTEST_TICKS)); /* the joints click once: "ready" */
    TX_P(pt, UART1, S_PREAMBLE);
    TX_P(pt, UART1, S_CTR_READY);
    byte = BYTE_READY;
    TX(pt, UART0, &byte, 1);
    for (;;) {
        RX_TL(pt, UART0, HANDSHAKE_RETRY_TICKS, byte);
        if (byte == BYTE_READY)
            break;
        byte = BYTE_READY;
        TX(pt, UART0, &byte, 1);
    }
    TX_P(pt, UART1, S_COMM_READY);
    byte = BYTE_LISTENING;
    TX(pt, UART0, &byte, 1);
#if HEXBOT_V2
    byte = dip_id(); /* the DIP switches are the module's id */
    TX(pt, UART0, &byte, 1);
    reporting = 1;
#endif
    TX_P(pt, UART1, S_CTR_LST);
    for (;;) {
        /* Listen(): '*' then five bytes: code a b c d */
        do {
            RX(pt, UART0, byte);
        } while (byte != BYTE_START);
        for (k = 0; k < 5; k++) {
#if HEXBOT_V2
            /* each within FRAME_BYTE_TICKS: after a long command the remains of a frame that
             * overran the input end in a silence and are dropped, not read as the next one */
            RX_TL2(pt, UART0, FRAME_BYTE_TICKS, msg[k], timed_out);
            if (timed_out)
                break;
#else
            RX(pt, UART0, msg[k]);
#endif
        }
        if (k < 5)
            continue;
        TX(pt, UART0, msg, 1); /* confirm to the comm board: echo the code */
        TX_P(pt, UART1, S_PREAMBLE);
        line[0] = TXT_ACK[0], line[1] = TXT_ACK[1], line[2] = TXT_ACK[2], line[3] = msg[0];
        line[4] = TXT_EOL[0], line[5] = TXT_EOL[1];
        TX(pt, UART1, line, 6);
        line[0] = TXT_MSG[0], line[1] = TXT_MSG[1], line[2] = TXT_MSG[2];
        for (k = 0; k < 5; k++)
            line[3 + k] = msg[k];
        line[8] = TXT_EOL[0], line[9] = TXT_EOL[1];
        TX(pt, UART1, line, 10);
#if HEXBOT_V2
        RX_TL2(pt, UART0, FRAME_BYTE_TICKS, byte, timed_out);
        if (timed_out || byte != BYTE_END)
            continue; /* not a whole frame: echoed, but not run */
#endif
        PT_CALL(pt, execute(msg[0], &msg[1]));
    }
    PT_END(pt);
}

/* Which coils are on: solenoids J1..J6, magnets positive and negative (bit s-1 = side s). */
static void coil_bits(uint8_t bits[3])
{
    uint8_t port[5];
    for (uint8_t p = 0; p < 5; p++)
        port[p] = board_port(p);
    bits[0] = bits[1] = bits[2] = 0;
    for (uint8_t s = 1; s <= 6; s++) {
        uint8_t b = (uint8_t)(1u << (s - 1));
        if (port[fw_byte(&JOINT_PORT[s])] & fw_byte(&JOINT_MASK[s]))
            bits[0] |= b;
        if (port[fw_byte(&POS_PORT[s])] & fw_byte(&POS_MASK[s]))
            bits[1] |= b;
        if (port[fw_byte(&NEG_PORT[s])] & fw_byte(&NEG_MASK[s]))
            bits[2] |= b;
    }
}

/* The on-time limits (ours, both profiles; bus/timing.py): a coil seen on at the end of every
 * step since tick t0 is switched off on tick t0 + its limit, and a "LIM" line names it on the
 * debug UART. A step looks at the coils only when they changed or when the earliest limit is
 * due, so the main loop stays as quick as before. Returns 1 if it switched a coil off. */
static uint8_t coil_on[3], guard_armed;
static uint16_t coil_since[3][6], guard_due;

static uint8_t coil_guard(const uint8_t bits[3])
{
    uint8_t over[3] = {0, 0, 0}, any = 0;
    uint16_t now = board_ticks();
    guard_armed = 0;
    for (uint8_t g = 0; g < 3; g++) {
        uint16_t limit = g ? MAGNET_ON_LIMIT_TICKS : SOLENOID_ON_LIMIT_TICKS;
        for (uint8_t s = 0; s < 6; s++) {
            uint8_t b = (uint8_t)(1u << s);
            if (!(bits[g] & b))
                continue;
            if (!(coil_on[g] & b))
                coil_since[g][s] = now;
            uint16_t due = (uint16_t)(coil_since[g][s] + limit);
            if ((int16_t)(now - due) >= 0) {
                over[g] |= b, any = 1;
            } else if (!guard_armed || (int16_t)(due - guard_due) < 0) {
                guard_due = due, guard_armed = 1;
            }
        }
        coil_on[g] = (uint8_t)(bits[g] & ~over[g]);
    }
    if (guard_armed)
        board_tick_reached(guard_due); /* on the host: be stepped when it is due */
    if (!any)
        return 0;
    for (uint8_t s = 1; s <= 6; s++) {
        uint8_t b = (uint8_t)(1u << (s - 1));
        if (over[0] & b)
            JxClose(s);
        if (over[1] & b)
            pin_change(POS_PORT, POS_MASK, s, 0);
        if (over[2] & b)
            pin_change(NEG_PORT, NEG_MASK, s, 0);
    }
    uint8_t out[8] = {TXT_LIM[0], TXT_LIM[1], TXT_LIM[2], over[0], over[1], over[2], TXT_EOL[0], TXT_EOL[1]};
    board_tx_queue(UART1, out, sizeof out);
    return 1;
}

static void report(const uint8_t bits[3])
{
    if (have_reported && bits[0] == reported[0] && bits[1] == reported[1] && bits[2] == reported[2])
        return;
    uint8_t out[8] = {TXT_ACT[0], TXT_ACT[1], TXT_ACT[2], bits[0], bits[1], bits[2], TXT_EOL[0], TXT_EOL[1]};
    if (board_tx_queue(UART1, out, sizeof out)) {
        have_reported = 1;
        reported[0] = bits[0], reported[1] = bits[1], reported[2] = bits[2];
    }
}

void program_step(void)
{
    uint8_t before[5], bits[3], changed = 0;
    for (uint8_t p = 0; p < 5; p++)
        before[p] = board_port(p) & ACTUATOR_BITS[p];
    co_main();
    for (uint8_t p = 0; p < 5; p++)
        changed |= (uint8_t)((board_port(p) & ACTUATOR_BITS[p]) != before[p]);
    if (!changed && !(guard_armed && board_tick_reached(guard_due)))
        return; /* the usual step: nothing to look at */
    coil_bits(bits);
    if (changed && reporting) /* one report for every bit a step changed, first: it is news */
        report(bits);
    if (coil_guard(bits) && reporting) {
        coil_bits(bits);
        report(bits);
    }
}

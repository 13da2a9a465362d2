/* What both programs share: the function table, the side/joint wrap, port bits and the
 * rotation walker. The tables come from hexbot_gen.h, written from bus/. */
#include "hexbot.h"

typedef struct { uint8_t code, board, nargs, v2; } fn_row;
typedef struct { uint8_t code, first, second; } mirror_row;

static const fn_row FN[] FW_CONST = FN_TABLE;
static const mirror_row MIRRORS[] FW_CONST = FN_MIRRORS;

static const int8_t STEPS_MCW[] FW_CONST = ROT_MCW;
static const int8_t STEPS_MCCW[] FW_CONST = ROT_MCCW;
static const int8_t STEPS_SCW[] FW_CONST = ROT_SCW;
#if HEXBOT_V2
static const int8_t STEPS_SCCW[] FW_CONST = ROT_SCCW;
#else
static const int8_t STEPS_SCCW[] FW_CONST = ROT_SCCW_AS_RAN; /* S(i-5) negative, as it ran */
#endif

uint8_t fold(int16_t i)
{
    if (i >= 1 && i <= 6)
        return (uint8_t)i; /* the usual case: no division on a chip without one */
    int16_t r = (i - 1) % 6;
    return (uint8_t)((r < 0 ? r + 6 : r) + 1);
}

static const fn_row *find(uint8_t code)
{
    for (uint8_t k = 0; k < sizeof(FN) / sizeof(FN[0]); k++)
        if (fw_byte(&FN[k].code) == code)
            return &FN[k];
    return 0;
}

uint8_t fn_board(uint8_t code)
{
    const fn_row *f = find(code);
    return f ? fw_byte(&f->board) : BOARD_NONE;
}

uint8_t fn_nargs(uint8_t code)
{
    const fn_row *f = find(code);
    return f ? fw_byte(&f->nargs) : 0;
}

uint8_t fn_is_v2(uint8_t code)
{
    const fn_row *f = find(code);
    return f ? fw_byte(&f->v2) : 0;
}

uint8_t fn_mirror(uint8_t code, uint8_t k)
{
    for (uint8_t r = 0; r < sizeof(MIRRORS) / sizeof(MIRRORS[0]); r++)
        if (fw_byte(&MIRRORS[r].code) == code)
            return fw_byte(k ? &MIRRORS[r].second : &MIRRORS[r].first);
    return 0;
}

void port_change(uint8_t port, uint8_t mask, uint8_t set)
{
    uint8_t v = board_port(port);
    board_port_write(port, set ? (uint8_t)(v | mask) : (uint8_t)(v & ~mask));
}

void pin_change(const uint8_t *ports, const uint8_t *masks, int16_t i, uint8_t set)
{
    uint8_t k = fold(i);
    port_change(fw_byte(&ports[k]), fw_byte(&masks[k]), set);
}

void pins_change(const uint8_t *ports, const uint8_t *masks, uint8_t set)
{
    uint8_t mask[5] = {0, 0, 0, 0, 0};
    for (uint8_t k = 1; k <= 6; k++)
        mask[fw_byte(&ports[k])] |= fw_byte(&masks[k]);
    for (uint8_t p = 0; p < 5; p++)
        if (mask[p])
            port_change(p, mask[p], set);
}

const int8_t *rotation_steps(uint8_t code)
{
    switch (code) {
    case FC_MCW: case FC_LMCW: return STEPS_MCW;
    case FC_MCCW: case FC_LMCCW: return STEPS_MCCW;
    case FC_SCW: case FC_LSCW: return STEPS_SCW;
    default: return STEPS_SCCW;
    }
}

/* Walk (op, arg) pairs until (0, 0): act on i + arg, or wait t1/t2/t3 ticks. The walk's
 * place is the caller's: r->step. */
uint8_t co_rotation(rotation_t *r, const int8_t *steps, uint8_t i, const uint8_t t[3],
                    rotation_action act)
{
    pt_t *pt = &r->pt;
    PT_BEGIN(pt);
    for (r->step = 0; fw_byte(&steps[r->step]); r->step += 2) {
        if (fw_byte(&steps[r->step]) == ROT_WAIT) {
            DELAY(pt, t[fw_byte(&steps[r->step + 1]) - 1]);
        } else {
            act(fw_byte(&steps[r->step]), (int16_t)i + fw_sbyte(&steps[r->step + 1]));
        }
    }
    PT_END(pt);
}

#if HEXBOT_V2
/* Act on the steps of one phase (up to its wait or the end); the place after it. */
static uint8_t rotation_phase(const int8_t *steps, uint8_t at, uint8_t i, rotation_action act)
{
    uint8_t op;
    while ((op = (uint8_t)fw_byte(&steps[at])) != 0 && op != ROT_WAIT) {
        act(op, (int16_t)i + fw_sbyte(&steps[at + 1]));
        at += 2;
    }
    return op == ROT_WAIT ? (uint8_t)(at + 2) : at;
}

uint8_t co_rotation_two(rotation_two_t *r, uint8_t dirs, const uint8_t i[2], const uint8_t t[3],
                        rotation_action act)
{
    pt_t *pt = &r->pt;
    PT_BEGIN(pt);
    r->at[0] = r->at[1] = 0;
    for (r->phase = 0; r->phase < 4; r->phase++) {
        for (uint8_t k = 0; k < 2; k++)
            r->at[k] = rotation_phase(rotation_steps(dirs >> k & 1 ? FC_SCW : FC_SCCW), r->at[k],
                                      i[k], act);
        if (r->phase < 3) {
            DELAY(pt, t[r->phase]);
        }
    }
    PT_END(pt);
}
#endif

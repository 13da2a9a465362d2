/* HexBot firmware: what both programs share.
 *
 * A program is a step function, Kilombo's way: the board layer calls program_step()
 * again and again (on the ATmega162 from its main loop, on the host whenever an event
 * happened), and the program runs until it has to wait for a byte, a free transmitter
 * or a tick, then returns. The waits are written as coroutines (a switch on a saved
 * line number, as in protothreads), so the program reads like the thesis's sequential
 * code while never blocking the caller.
 *
 * Rules for a coroutine body: all state that lives across a wait is static (comm.c keeps
 * it in one struct per coroutine: its pt_t and those locals, named after it); at most one
 * PT_ macro per source line; no `switch` in a coroutine body (put it in a helper). */
#ifndef HEXBOT_H
#define HEXBOT_H

#include <stdint.h>

#include "hexbot_gen.h"

#ifndef HEXBOT_V2
#define HEXBOT_V2 1 /* protocol v2; 0 = the thesis-2009 firmware's observable behaviour */
#endif

/* --- constants in flash on the ATmega162, plain data on the host --- */
#ifdef __AVR__
#include <avr/pgmspace.h>
#define FW_CONST PROGMEM
#define fw_byte(p) pgm_read_byte(p)
#else
#define FW_CONST
#define fw_byte(p) (*(const uint8_t *)(p))
#endif
#define fw_sbyte(p) ((int8_t)fw_byte(p))

/* --- the board layer (board_avr.c on the chip; the host's own elsewhere) --- */
enum { PORT_A, PORT_B, PORT_C, PORT_D, PORT_E };
enum { UART0, UART1 };

/* DDR from `outputs`, pull-ups (PORT bits of inputs) from `pullups`; UARTs, Timer0 tick. */
void board_init(const uint8_t outputs[5], const uint8_t pullups[5]);
uint16_t board_ticks(void);                  /* Timer0 overflows since power-up */
uint8_t board_tick_reached(uint16_t target); /* board_ticks() has reached target (mod 2^16) */
uint8_t board_rx_ready(uint8_t uart);        /* RXC: a received byte is waiting */
uint8_t board_rx_read(uint8_t uart);
uint8_t board_tx_ready(uint8_t uart);        /* UDRE, and nothing queued in the background */
void board_tx_write(uint8_t uart, uint8_t byte);
/* TransmitByte for data[k..len): hands over what the UART takes now and returns the new
 * k; len once the last byte is in UDR (the program goes on then). `flash`: data is FW_CONST. */
uint8_t board_tx_some(uint8_t uart, const uint8_t *data, uint8_t flash, uint8_t k, uint8_t len);
/* Send in the background (UDRE interrupt); 0 if the queue is full. */
uint8_t board_tx_queue(uint8_t uart, const uint8_t *data, uint8_t n);
uint8_t board_port(uint8_t port);            /* PORTx as last written */
void board_port_write(uint8_t port, uint8_t value);
uint8_t board_pins(uint8_t port);            /* PINx: levels on the pins */

/* --- each program provides --- */
extern const uint8_t program_outputs[5];     /* DDR: which pins are outputs */
extern const uint8_t program_pullups[5];     /* inputs pulled up (DIP, optical switches) */
void program_step(void);

/* --- coroutines --- */
typedef struct {
    uint16_t lc; /* where to resume: a source line, 0 = start */
    uint16_t t0; /* the tick a wait ends on */
    uint8_t k;   /* bytes of a transmission handed over */
} pt_t;

enum { PT_WAITING = 0, PT_DONE = 1 };

#define PT_BEGIN(pt) switch ((pt)->lc) { case 0:
#define PT_END(pt) } (pt)->lc = 0; return PT_DONE
#define PT_EXIT(pt) do { (pt)->lc = 0; return PT_DONE; } while (0)
#define PT_WAIT_UNTIL(pt, cond) \
    do { (pt)->lc = __LINE__; case __LINE__: if (!(cond)) return PT_WAITING; } while (0)
/* Run a child coroutine (a call that returns PT_DONE when it has finished). */
#define PT_CALL(pt, call) PT_WAIT_UNTIL(pt, (call) == PT_DONE)

/* DelayXts(n): resume on the n-th Timer0 overflow after now. */
#define DELAY(pt, ticks) \
    do { (pt)->t0 = (uint16_t)(board_ticks() + (ticks)); \
         PT_WAIT_UNTIL(pt, board_tick_reached((pt)->t0)); } while (0)
/* Wait for the overflow that makes board_ticks() == target (at once if it has passed). */
#define WAIT_TICK(pt, target) \
    do { (pt)->t0 = (target); PT_WAIT_UNTIL(pt, board_tick_reached((pt)->t0)); } while (0)
/* ReceiveByte */
#define RX(pt, uart, dst) \
    do { PT_WAIT_UNTIL(pt, board_rx_ready(uart)); (dst) = board_rx_read(uart); } while (0)
/* ReceiveByteTL(n): the byte, or ACK_TIMEOUT ('~') on the n-th overflow: a received '~'
 * reads as a timeout, as in the thesis. */
#define RX_TL(pt, uart, ticks, dst) \
    do { (pt)->t0 = (uint16_t)(board_ticks() + (ticks)); \
         PT_WAIT_UNTIL(pt, board_rx_ready(uart) || board_tick_reached((pt)->t0)); \
         (dst) = board_rx_ready(uart) ? board_rx_read(uart) : ACK_TIMEOUT; } while (0)
/* The same, telling a timeout apart from a received byte (v2): `timed_out` is 1 or 0. */
#define RX_TL2(pt, uart, ticks, dst, timed_out) \
    RX_UNTIL(pt, uart, (uint16_t)(board_ticks() + (ticks)), dst, timed_out)
/* The same with a deadline: the overflow that makes board_ticks() == target. */
#define RX_UNTIL(pt, uart, target, dst, timed_out) \
    do { (pt)->t0 = (target); \
         PT_WAIT_UNTIL(pt, board_rx_ready(uart) || board_tick_reached((pt)->t0)); \
         (timed_out) = !board_rx_ready(uart); \
         (dst) = (timed_out) ? ACK_TIMEOUT : board_rx_read(uart); } while (0)
/* TransmitByte for each byte of a RAM buffer: done when the last one is in UDR. */
#define TX_BYTES(pt, uart, data, flash, len) \
    do { (pt)->k = 0; PT_WAIT_UNTIL(pt, ((pt)->k = board_tx_some(uart, (const uint8_t *)(data), \
                                                                 flash, (pt)->k, len)) >= (len)); } while (0)
#define TX(pt, uart, data, len) TX_BYTES(pt, uart, data, 0, len)
/* The same for a FW_CONST string. */
#define TX_P(pt, uart, str) TX_BYTES(pt, uart, str, 1, sizeof(str) - 1)

/* --- shared helpers (common.c) --- */
enum { BOARD_NONE = 0, BOARD_CONTROL = 1, BOARD_COMM = 2 };

uint8_t fold(int16_t i);                     /* the firmware's wrap of a side/joint into 1..6 */
uint8_t fn_board(uint8_t code);              /* BOARD_* of a code (Table 3-7) */
uint8_t fn_nargs(uint8_t code);
uint8_t fn_is_v2(uint8_t code);
uint8_t fn_mirror(uint8_t code, uint8_t k);  /* k-th LED mirror of a control code, or 0 */
void port_change(uint8_t port, uint8_t mask, uint8_t set);
/* Pin i (folded into 1..6) of a pin table (ports[], masks[] of hexbot_gen.h): set or clear. */
void pin_change(const uint8_t *ports, const uint8_t *masks, int16_t i, uint8_t set);
/* All six pins of a table: one write per port, in port order (as the model does). */
void pins_change(const uint8_t *ports, const uint8_t *masks, uint8_t set);

/* One rotation (bus/rotations.py) through a board's own actions. Its state is the
 * caller's: a rotation_t for each place that runs one. */
enum { ROT_OPEN = 1, ROT_POS, ROT_NEG, ROT_CLOSE_ALL, ROT_OFF_ALL, ROT_WAIT };
typedef void (*rotation_action)(uint8_t op, int16_t index);
typedef struct {
    pt_t pt;
    uint8_t step; /* the (op, arg) pair being walked */
} rotation_t;
const int8_t *rotation_steps(uint8_t code); /* code 21..24 or 56..59 */
uint8_t co_rotation(rotation_t *r, const int8_t *steps, uint8_t i, const uint8_t t[3],
                    rotation_action act);
#if HEXBOT_V2
/* Two substrate programs at once (STwo, LSTwo; bus.rotations.perform_together): bit k of
 * dirs = program k is SCW (else SCCW), about i[k]; each phase runs both, then waits. */
typedef struct {
    pt_t pt;
    uint8_t phase, at[2];
} rotation_two_t;
uint8_t co_rotation_two(rotation_two_t *r, uint8_t dirs, const uint8_t i[2], const uint8_t t[3],
                        rotation_action act);
#endif

#endif

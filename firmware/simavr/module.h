/* One HexBot module (comm + control ATmega162 at 1 MHz) in simavr: what the harness
 * (hexbot_simavr.c: one module on ptys, on the wall clock) and the library (hexbot_lib.c:
 * modules in-process, on the caller's clock) share.  The two cores, their images and
 * EEPROM records, the pins the outside world drives (DIP and optical switches), the wires
 * into their USARTs (receiver.h) with UART0 wired between the boards, and the lockstep that
 * runs them: the core behind always steps next, and a heartbeat bounds how far SLEEP jumps. */
#ifndef HEXBOT_MODULE_H
#define HEXBOT_MODULE_H

#include <stddef.h>
#include <stdint.h>

#include "sim_avr.h"
#include "receiver.h"

#define F_CPU 1000000ULL
#define FLASH_SIZE 16384

enum { COMM, CONTROL };
extern const char *const BOARD[2];	/* "comm", "control" */

typedef struct board {
	int id;
	avr_t *avr;
	int halted;
	uint8_t port[5];	/* last reported PORTx values */
	uint8_t ddr[5];		/* ... and DDRx (the harness's --trace ddr) */
} board_t;

typedef struct module {
	board_t boards[2];
	line_t lines[2][2];			/* [board][usart]: the wires into the receivers */
	avr_cycle_count_t tx_busy[2][2];	/* each transmitter's wire */
} module_t;

/* Board `id`: a new core with the image `elf` loaded (`what` names it in the message of
 * an unreadable file, e.g. "comm ELF"), the EEPROM's board-kind record `record` (0: erased),
 * its lines attached and a heartbeat of `heartbeat` cycles.  0, or 1 (out of memory) or 2
 * (the image) with one line in `err`. */
int module_board(module_t *m, int id, const char *elf, const char *what, int record,
		 avr_cycle_count_t heartbeat, char *err, size_t errlen);

/* The optical switches (bit k-1: a neighbour on side k, which pulls that pin to the active
 * level) on the comm core, the DIP switches on the control core. */
void module_set_switches(avr_t *avr, int switches);
void module_set_dip(avr_t *avr, int dip);

/* A byte that USART n of board id started to send now (UART_IRQ_OUTPUT): its start bit,
 * when its wire is free; a UART0 byte goes onto the other board's line.  *frame: its
 * length in cycles. */
avr_cycle_count_t module_tx(module_t *m, int id, int n, uint8_t b, avr_cycle_count_t *frame);

/* Run the core behind until both have reached `until`: 0 then.  A core that sleeps with
 * interrupts off halts (1: *who is the board; call again to go on); one that crashes stops
 * (-1, halted too, with one line in `err` naming it and the faulting instruction's PC). */
int module_run(module_t *m, avr_cycle_count_t until, board_t **who, char *err, size_t errlen);

/* The cycle the running core behind has reached; ~0 when both have halted. */
avr_cycle_count_t module_now(const module_t *m);

void module_free(module_t *m);

#endif

/* Lines: the wire into one USART receiver of a simavr core, and the receiver model that
 * the harness (hexbot_simavr.c) and the library (hexbot_lib.c) share.
 *
 * Every byte into a USART travels as a frame on a line: it starts when the sender's wire is
 * free, ends one frame later, and RXC rises at its end.  The receiver holds two bytes plus
 * one in the shift register; the next start bit loses the shifted one (DOR), as on the
 * chip.  simavr 1.6's own 64-byte input FIFO is never used past that.  A sender whose bit
 * time is more than 4 % off the receiver's gives a framing error (FE). */
#ifndef HEXBOT_RECEIVER_H
#define HEXBOT_RECEIVER_H

#include <stdint.h>

#include "sim_avr.h"

#define LINE_MAX_QUEUE 65536	/* bytes waiting to go onto one wire */

enum { F_WAIT, F_SHIFT, F_HELD };
typedef struct frame {
	uint8_t value, state;
	avr_cycle_count_t start, end, bit;	/* bit: the sender's bit time */
} frame_t;

typedef struct line line_t;
struct line {
	avr_t *avr;		/* the receiving core */
	int board, n;		/* its board (COMM, CONTROL) and USART number */
	/* A gated line (the comm board's IR receiver behind the multiplexer) is asked at a
	 * frame's start bit (whole = 0) and at its end (whole = 1) whether the frame counts;
	 * 0 drops it.  NULL: every frame counts. */
	int (*gate)(line_t *l, const frame_t *f, int whole);
	/* A frame held in the shift register is lost at the next start bit `at` (DOR). */
	void (*overrun)(line_t *l, avr_cycle_count_t at, uint8_t lost);
	void *owner;		/* for the callbacks */
	frame_t *q;
	size_t cap, head, len;
	avr_cycle_count_t busy;		/* the wire carries a frame until then */
	avr_cycle_count_t last_end;	/* end of the frame last handed to simavr */
	unsigned long overruns, gated, rx_off, full;
};

/* The line into USART n of board `board`'s core (a read of its UDR serves the line). */
void line_attach(line_t *l, avr_t *avr, int board, int n);

/* A frame of `frame` cycles, sent with `bit` cycles a bit, that starts at `at` or when the
 * wire is free. */
void line_push(line_t *l, uint8_t value, avr_cycle_count_t at, avr_cycle_count_t frame,
	       avr_cycle_count_t bit);

void line_free(line_t *l);

/* Defined by the program: what running out of memory does (the harness: one line and exit
 * 1; the library: abort). */
void hexbot_out_of_memory(void);

#endif

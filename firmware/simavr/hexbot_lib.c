/* libhexbot-simavr: HexBot modules (comm + control ATmega162 at 1 MHz) in simavr, in-process,
 * for module_sim/simavr.py. The harness (hexbot_simavr.c) runs one module on ptys on the wall
 * clock; this library runs any number of them on the caller's clock: the caller advances a
 * module to a cycle (hbl_run), feeds received bytes at their stop bits (hbl_rx), sets the
 * optical switches at a cycle (hbl_switches_at) and collects what the two boards did, each
 * with its cycle: bytes whose start bit began (UART0 both ways, the comm board's UART1 into
 * the IR multiplexer, the control board's UART1 to the debug terminal), PORTx changes,
 * receiver overruns (hbl_events).
 *
 * The module itself is the harness's (module.c): the two cores in lockstep (the one behind
 * steps next; a heartbeat bounds how far SLEEP jumps, so they stay within HEARTBEAT cycles,
 * well inside the 2080 cycles of a UART0 frame), their UART0s wired together, and the
 * receiver model (receiver.c): one frame at a time, RXC at the end of the frame, two bytes in
 * the FIFO and one in the shift register, the next start bit overruns (DOR). What the comm
 * board's UART1 receives is the caller's (the IR medium and the multiplexer gate are
 * module_sim's). */
#define _GNU_SOURCE
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "atmega162.h"
#include "hexbot_pins.h"
#include "module.h"

#define HBL_ABI 1
#define HEARTBEAT 512		/* longest SLEEP jump, in cycles (a UART0 frame is 2080) */
#define PENDING_SWITCHES 16

enum { EV_TX = 1, EV_PORT = 2, EV_OVERRUN = 3, EV_HALT = 4 };

/* One thing a board did (16 bytes; module_sim/simavr.py reads them as an array). */
typedef struct hbl_event {
	uint64_t t;		/* cycle since power-up: a byte's start bit, a write's instant */
	uint8_t kind, board, unit, value;	/* unit: the USART or port; value: byte or PORTx */
	uint32_t frame;		/* EV_TX: the frame's length in cycles */
} hbl_event_t;

typedef struct hbl_module hbl_module_t;

typedef struct tx_ctx {
	hbl_module_t *m;
	int id, n;
} tx_ctx_t;

typedef struct port_ctx {
	hbl_module_t *m;
	int id, port;
} port_ctx_t;

struct hbl_module {
	module_t mod;		/* the two cores and their wires (module.h) */
	tx_ctx_t tx_ctx[2][2];
	port_ctx_t port_ctx[2][5];
	struct { avr_cycle_count_t at; uint8_t mask; } pending[PENDING_SWITCHES];
	size_t npending;
	hbl_event_t *events;
	size_t nevents, cap_events;
	char error[256];
};

void hexbot_out_of_memory(void)
{
	abort();
}

/* --- errors and simavr's own messages ----------------------------------------------- */

static void quiet_logger(avr_t *avr, const int level, const char *fmt, va_list ap)
{
	(void)avr;
	(void)level;
	(void)fmt;
	(void)ap;	/* errors reach the caller as one line of ours (hbl_error) */
}

/* --- events, kept in time order (stable: equal times keep their order) --------------- */

static void event(hbl_module_t *m, avr_cycle_count_t t, int kind, int board, int unit,
		  int value, uint32_t frame)
{
	if (m->nevents == m->cap_events) {
		size_t cap = m->cap_events ? 2 * m->cap_events : 256;
		hbl_event_t *e = realloc(m->events, cap * sizeof *e);
		if (!e)
			abort();
		m->events = e;
		m->cap_events = cap;
	}
	size_t i = m->nevents++;
	while (i && m->events[i - 1].t > t) {
		m->events[i] = m->events[i - 1];
		i--;
	}
	m->events[i] = (hbl_event_t){ t, (uint8_t)kind, (uint8_t)board, (uint8_t)unit,
				      (uint8_t)value, frame };
}

/* --- what the boards do ------------------------------------------------------------- */

static void on_overrun(line_t *l, avr_cycle_count_t at, uint8_t lost)
{
	event(l->owner, at, EV_OVERRUN, l->board, l->n, lost, 0);
}

/* The core raises UART_IRQ_OUTPUT when a byte's start bit begins (atmega162.c). */
static void on_tx(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	tx_ctx_t *c = param;
	avr_cycle_count_t frame;
	avr_cycle_count_t start = module_tx(&c->m->mod, c->id, c->n, value & 0xFF, &frame);
	event(c->m, start, EV_TX, c->id, c->n, value & 0xFF, (uint32_t)frame);
}

static void on_port(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	port_ctx_t *c = param;
	board_t *b = &c->m->mod.boards[c->id];
	if (b->port[c->port] == (uint8_t)value)
		return;
	b->port[c->port] = (uint8_t)value;
	event(c->m, b->avr->cycle, EV_PORT, c->id, c->port, value & 0xFF, 0);
}

static avr_cycle_count_t switches_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
	hbl_module_t *m = param;
	size_t i = 0;
	for (; i < m->npending && m->pending[i].at <= when; i++)
		module_set_switches(avr, m->pending[i].mask);
	memmove(m->pending, m->pending + i, (m->npending - i) * sizeof m->pending[0]);
	m->npending -= i;
	return m->npending ? m->pending[0].at : 0;
}

/* --- set-up ------------------------------------------------------------------------- */

static int board_setup(hbl_module_t *m, int id, const char *elf)
{
	char what[32];
	snprintf(what, sizeof what, "the %s image", BOARD[id]);
	if (module_board(&m->mod, id, elf, what, id == COMM ? BOARD_KIND_COMM : BOARD_KIND_CONTROL,
			 HEARTBEAT, m->error, sizeof m->error))
		return -1;
	avr_t *avr = m->mod.boards[id].avr;
	for (int n = 0; n < 2; n++) {
		line_t *l = &m->mod.lines[id][n];
		l->overrun = on_overrun;
		l->owner = m;
		m->tx_ctx[id][n] = (tx_ctx_t){ m, id, n };
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0' + n),
						      UART_IRQ_OUTPUT), on_tx, &m->tx_ctx[id][n]);
	}
	for (int p = 0; p < 5; p++) {
		m->port_ctx[id][p] = (port_ctx_t){ m, id, p };
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A' + p),
						      IOPORT_IRQ_REG_PORT), on_port, &m->port_ctx[id][p]);
	}
	return 0;
}

/* --- the API (module_sim/simavr.py) --------------------------------------------------- */

int hbl_abi(void) { return HBL_ABI; }

size_t hbl_event_size(void) { return sizeof(hbl_event_t); }

void hbl_free(hbl_module_t *m)
{
	if (!m)
		return;
	module_free(&m->mod);
	free(m->events);
	free(m);
}

/* A module at power-up: the two images (ELF), the DIP switches, the optical switches (bit
 * k-1: a neighbour on side k). NULL and a line in `err` when it cannot be made. */
hbl_module_t *hbl_new(const char *comm_elf, const char *control_elf, int dip, int switches,
		      char *err, size_t errlen)
{
	static int quiet;
	if (!quiet) {
		avr_global_logger_set(quiet_logger);
		quiet = 1;
	}
	hbl_module_t *m = calloc(1, sizeof *m);
	if (!m) {
		snprintf(err, errlen, "out of memory");
		return NULL;
	}
	if (board_setup(m, COMM, comm_elf) || board_setup(m, CONTROL, control_elf)) {
		snprintf(err, errlen, "%s", m->error);
		hbl_free(m);
		return NULL;
	}
	module_set_dip(m->mod.boards[CONTROL].avr, dip);
	module_set_switches(m->mod.boards[COMM].avr, switches);
	return m;
}

const char *hbl_error(hbl_module_t *m) { return m->error; }

/* The module's time: the cycle the core behind has reached. */
uint64_t hbl_now(hbl_module_t *m)
{
	avr_cycle_count_t t = module_now(&m->mod);
	if (t == ~(avr_cycle_count_t)0) {	/* both halted: the later one's time */
		avr_t *a = m->mod.boards[0].avr, *b = m->mod.boards[1].avr;
		t = a->cycle > b->cycle ? a->cycle : b->cycle;
	}
	return t;
}

/* Run both cores until both have reached `until` (a cycle). 0, or -1 when a core crashed
 * (hbl_error names it); a core that sleeps with interrupts off halts (an EV_HALT event). */
int hbl_run(hbl_module_t *m, uint64_t until)
{
	board_t *b;
	int r;
	while ((r = module_run(&m->mod, until, &b, m->error, sizeof m->error)) > 0)
		event(m, b->avr->cycle, EV_HALT, b->id, 0, 0, 0);
	return r;
}

/* Stop a board for good (a test's board that never answers). */
void hbl_halt(hbl_module_t *m, int board)
{
	m->mod.boards[board ? 1 : 0].halted = 1;
}

/* A byte into USART `uart` of `board` that ended (its stop bit) at cycle `end`, sent with
 * `bit` cycles a bit, `frame` cycles in all. */
void hbl_rx(hbl_module_t *m, int board, int uart, uint8_t byte, uint64_t end, uint32_t frame,
	    uint32_t bit)
{
	line_t *l = &m->mod.lines[board ? 1 : 0][uart ? 1 : 0];
	line_push(l, byte, end > frame ? end - frame : 0, frame, bit);
}

/* The optical switches become `switches` at cycle `at` (at once if the comm core is past it). */
int hbl_switches_at(hbl_module_t *m, int switches, uint64_t at)
{
	avr_t *avr = m->mod.boards[COMM].avr;
	if (at <= avr->cycle) {
		module_set_switches(avr, switches);
		return 0;
	}
	if (m->npending == PENDING_SWITCHES)
		return -1;
	size_t i = m->npending++;
	while (i && m->pending[i - 1].at > at) {
		m->pending[i] = m->pending[i - 1];
		i--;
	}
	m->pending[i].at = at;
	m->pending[i].mask = (uint8_t)switches;
	avr_cycle_timer_register(avr, m->pending[0].at - avr->cycle, switches_timer, m);
	return 0;
}

/* What the boards did up to `upto` (a cycle both cores have passed), in time order: the
 * events are copied to `out` (at most `max`) and forgotten; returns how many. */
size_t hbl_take(hbl_module_t *m, uint64_t upto, hbl_event_t *out, size_t max)
{
	size_t i = 0;
	for (; i < m->nevents && i < max && m->events[i].t <= upto; i++)
		out[i] = m->events[i];
	memmove(m->events, m->events + i, (m->nevents - i) * sizeof *m->events);
	m->nevents -= i;
	return i;
}

/* Frame and bit length of a USART, in cycles (from its UBRR, U2X and UCSRC). */
uint32_t hbl_frame_cycles(hbl_module_t *m, int board, int uart)
{
	return (uint32_t)atmega162_uart_frame_cycles(m->mod.boards[board ? 1 : 0].avr, uart);
}

uint32_t hbl_bit_cycles(hbl_module_t *m, int board, int uart)
{
	return (uint32_t)atmega162_uart_bit_cycles(m->mod.boards[board ? 1 : 0].avr, uart);
}

/* Receiver counters: overruns, bytes lost with the receiver off or the line full. */
unsigned long hbl_overruns(hbl_module_t *m)
{
	unsigned long n = 0;
	for (int i = 0; i < 4; i++)
		n += m->mod.lines[i / 2][i % 2].overruns;
	return n;
}

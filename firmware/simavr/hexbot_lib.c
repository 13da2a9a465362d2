/* libhexbot-simavr: HexBot modules (comm + control ATmega162 at 1 MHz) in simavr, in-process,
 * for module_sim/simavr.py. The harness (hexbot_simavr.c) runs one module on ptys on the wall
 * clock; this library runs any number of them on the caller's clock: the caller advances a
 * module to a cycle (hbl_run), feeds received bytes at their stop bits (hbl_rx), sets the
 * optical switches at a cycle (hbl_switches_at) and collects what the two boards did, each
 * with its cycle: bytes whose start bit began (UART0 both ways, the comm board's UART1 into
 * the IR multiplexer, the control board's UART1 to the debug terminal), PORTx changes,
 * receiver overruns (hbl_events).
 *
 * Within a module the two cores run in lockstep (the one behind steps next; a heartbeat
 * bounds how far SLEEP jumps, so they stay within HEARTBEAT cycles, well inside the 2080
 * cycles of a UART0 frame) and their UART0s are wired here, with the harness's receiver
 * model: one frame at a time, RXC at the end of the frame, two bytes in the FIFO and one in
 * the shift register, the next start bit overruns (DOR). What the comm board's UART1
 * receives is the caller's (the IR medium and the multiplexer gate are module_sim's). */
#define _GNU_SOURCE
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_cycle_timers.h"
#include "sim_interrupts.h"
#include "sim_regbit.h"
#include "avr_eeprom.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "atmega162.h"
#include "hexbot_pins.h"

#define HBL_ABI 1
#define F_CPU 1000000ULL
#define HEARTBEAT 512		/* longest SLEEP jump, in cycles (a UART0 frame is 2080) */
#define LINE_MAX_QUEUE 65536
#define FLASH_SIZE 16384
#define PENDING_SWITCHES 16

enum { COMM, CONTROL };
static const char *const BOARD[2] = { "comm", "control" };

enum { EV_TX = 1, EV_PORT = 2, EV_OVERRUN = 3, EV_HALT = 4 };

/* One thing a board did (16 bytes; module_sim/simavr.py reads them as an array). */
typedef struct hbl_event {
	uint64_t t;		/* cycle since power-up: a byte's start bit, a write's instant */
	uint8_t kind, board, unit, value;	/* unit: the USART or port; value: byte or PORTx */
	uint32_t frame;		/* EV_TX: the frame's length in cycles */
} hbl_event_t;

typedef struct hbl_module hbl_module_t;

typedef struct board {
	hbl_module_t *m;
	int id;
	avr_t *avr;
	int halted;
	uint8_t port[5];	/* last reported PORTx values */
} board_t;

enum { F_WAIT, F_SHIFT, F_HELD };
typedef struct frame {
	uint8_t value, state;
	avr_cycle_count_t start, end, bit;
} frame_t;

typedef struct line {		/* the wire into one USART receiver */
	board_t *rx;
	int n;
	frame_t *q;
	size_t cap, head, len;
	avr_cycle_count_t busy, last_end;
	unsigned long overruns, rx_off, full;
} line_t;

typedef struct tx_ctx {
	hbl_module_t *m;
	int id, n;
} tx_ctx_t;

typedef struct port_ctx {
	hbl_module_t *m;
	int id, port;
} port_ctx_t;

struct hbl_module {
	board_t boards[2];
	line_t lines[2][2];		/* [board][usart] */
	avr_cycle_count_t tx_busy[2][2];
	tx_ctx_t tx_ctx[2][2];
	port_ctx_t port_ctx[2][5];
	struct { avr_cycle_count_t at; uint8_t mask; } pending[PENDING_SWITCHES];
	size_t npending;
	hbl_event_t *events;
	size_t nevents, cap_events;
	char error[256];
};

/* --- errors and simavr's own messages ----------------------------------------------- */

static void set_error(hbl_module_t *m, const char *fmt, ...)
{
	va_list ap;
	va_start(ap, fmt);
	vsnprintf(m->error, sizeof m->error, fmt, ap);
	va_end(ap);
}

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

/* --- lines: frames into a USART receiver (hexbot_simavr.c's model) ------------------- */

static unsigned fifo_count(avr_uart_t *p)
{
	return (unsigned)(p->input.write + uart_fifo_fifo_size - p->input.read) &
	       (uart_fifo_fifo_size - 1);
}

static void line_service(line_t *l);

static avr_cycle_count_t line_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
	(void)avr;
	(void)when;
	line_service(param);
	return 0;
}

static void line_pop(line_t *l)
{
	l->head = (l->head + 1) % l->cap;
	l->len--;
}

static void line_deliver(line_t *l, frame_t *f)
{
	avr_t *avr = l->rx->avr;
	avr_uart_t *p = atmega162_uart(avr, l->n);
	if (!avr_regbit_get(avr, p->rxen)) {
		l->rx_off++;
		return;
	}
	avr_cycle_count_t rx_bit = atmega162_uart_bit_cycles(avr, l->n);
	avr_cycle_count_t diff = rx_bit > f->bit ? rx_bit - f->bit : f->bit - rx_bit;
	uint32_t v = f->value | (diff * 25 > f->bit ? UART_INPUT_FE : 0);
	avr_raise_irq(p->io.irq + UART_IRQ_INPUT, v);
	l->last_end = f->end;
}

static void line_service(line_t *l)
{
	avr_t *avr = l->rx->avr;
	avr_uart_t *p = atmega162_uart(avr, l->n);
	avr_cycle_count_t now = avr->cycle, wake = 0;

	while (l->len && !wake) {
		frame_t *f = &l->q[l->head];
		unsigned n = fifo_count(p);
		if (f->state == F_WAIT) {
			if (now < f->start) {
				wake = f->start;
				break;
			}
			f->state = F_SHIFT;
		}
		if (f->state == F_SHIFT) {
			if (!n) {
				/* simavr raises RXC one of its frames after the input: time it
				 * so that lands on the end of this frame */
				avr_cycle_count_t t = f->end > p->cycles_per_byte ?
						      f->end - p->cycles_per_byte : 0;
				if (t < f->start)
					t = f->start;
				if (now < t) {
					wake = t;
					break;
				}
				line_deliver(l, f);
				line_pop(l);
				continue;
			}
			if (now < f->end) {
				wake = f->end;
				break;
			}
			f->state = F_HELD;
		}
		/* F_HELD: complete, in the shift register until the buffer has room */
		if (n < 2) {
			line_deliver(l, f);
			line_pop(l);
			continue;
		}
		frame_t *next = l->len > 1 ? &l->q[(l->head + 1) % l->cap] : NULL;
		if (next && now >= next->start) {
			l->overruns++;
			avr_regbit_setto(avr, p->dor, 1);
			event(l->rx->m, next->start, EV_OVERRUN, l->rx->id, l->n, f->value, 0);
			line_pop(l);
			continue;
		}
		wake = next ? next->start : 0;	/* else a read of UDR calls us */
		break;
	}

	unsigned n = fifo_count(p);
	if (n && !avr_regbit_get(avr, p->rxc.raised)) {
		avr_cycle_count_t due = n >= 2 || l->last_end <= now ? now : l->last_end;
		if (due <= now)
			avr_raise_interrupt(avr, &p->rxc);
		else if (!wake || due < wake)
			wake = due;
	}
	if (wake)
		avr_cycle_timer_register(avr, wake - now, line_timer, l);
	else
		avr_cycle_timer_cancel(avr, line_timer, l);
}

static void line_push(line_t *l, uint8_t value, avr_cycle_count_t at,
		      avr_cycle_count_t frame, avr_cycle_count_t bit)
{
	if (l->len >= LINE_MAX_QUEUE) {
		l->full++;
		return;
	}
	if (l->len == l->cap) {
		size_t cap = l->cap ? 2 * l->cap : 64;
		frame_t *q = malloc(cap * sizeof *q);
		if (!q)
			abort();
		for (size_t i = 0; i < l->len; i++)
			q[i] = l->q[(l->head + i) % l->cap];
		free(l->q);
		l->q = q;
		l->cap = cap;
		l->head = 0;
	}
	avr_cycle_count_t start = at > l->busy ? at : l->busy;
	l->busy = start + frame;
	l->q[(l->head + l->len++) % l->cap] = (frame_t){ value, F_WAIT, start, start + frame, bit };
	line_service(l);
}

static void on_udr_read(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	(void)avr;
	(void)addr;
	(void)v;
	line_service(param);
}

/* --- what the boards do ------------------------------------------------------------- */

/* The core raises UART_IRQ_OUTPUT when a byte's start bit begins (atmega162.c). */
static void on_tx(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	tx_ctx_t *c = param;
	hbl_module_t *m = c->m;
	avr_t *avr = m->boards[c->id].avr;
	avr_cycle_count_t now = avr->cycle, frame = atmega162_uart_frame_cycles(avr, c->n);
	avr_cycle_count_t start = now > m->tx_busy[c->id][c->n] ? now : m->tx_busy[c->id][c->n];
	uint8_t b = value & 0xFF;
	m->tx_busy[c->id][c->n] = start + frame;
	if (c->n == 0)
		line_push(&m->lines[!c->id][0], b, start, frame, atmega162_uart_bit_cycles(avr, 0));
	event(m, start, EV_TX, c->id, c->n, b, (uint32_t)frame);
}

static void on_port(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	port_ctx_t *c = param;
	board_t *b = &c->m->boards[c->id];
	if (b->port[c->port] == (uint8_t)value)
		return;
	b->port[c->port] = (uint8_t)value;
	event(c->m, b->avr->cycle, EV_PORT, c->id, c->port, value & 0xFF, 0);
}

static avr_cycle_count_t heartbeat(avr_t *avr, avr_cycle_count_t when, void *param)
{
	(void)avr;
	(void)param;
	return when + HEARTBEAT;
}

/* --- inputs ------------------------------------------------------------------------- */

static void set_inputs(avr_t *avr, int port, uint8_t mask, uint8_t value)
{
	char name = 'A' + port;
	avr_ioport_external_t e = { .name = name, .mask = mask, .value = value };
	avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL(name), &e);
	for (int i = 0; i < 8; i++)
		if (mask & (1 << i))
			avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(name), i),
				      (value >> i) & 1);
}

/* Bit k-1 of `switches`: a neighbour on side k, which pulls that pin to the active level. */
static void set_switches(avr_t *avr, int switches)
{
	uint8_t mask[5] = { 0 }, value[5] = { 0 };
	for (int k = 1; k <= 6; k++) {
		int closed = (switches >> (k - 1)) & 1;
		mask[PINS_SWITCH_PORTS[k]] |= PINS_SWITCH_MASKS[k];
		if (closed != PINS_SWITCH_ACTIVE_LOW)
			value[PINS_SWITCH_PORTS[k]] |= PINS_SWITCH_MASKS[k];
	}
	for (int p = 0; p < 5; p++)
		if (mask[p])
			set_inputs(avr, p, mask[p], value[p]);
}

static void set_dip(avr_t *avr, int dip)
{
	set_inputs(avr, PINS_DIP_PORT, 0xFF, (uint8_t)(PINS_DIP_ACTIVE_LOW ? ~dip : dip));
}

static avr_cycle_count_t switches_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
	hbl_module_t *m = param;
	size_t i = 0;
	for (; i < m->npending && m->pending[i].at <= when; i++)
		set_switches(avr, m->pending[i].mask);
	memmove(m->pending, m->pending + i, (m->npending - i) * sizeof m->pending[0]);
	m->npending -= i;
	return m->npending ? m->pending[0].at : 0;
}

/* --- set-up ------------------------------------------------------------------------- */

static int load_elf(hbl_module_t *m, board_t *b, const char *path)
{
	unsigned char h[20];
	FILE *f = fopen(path, "rb");
	if (!f) {
		set_error(m, "cannot read the %s image %s: %s", BOARD[b->id], path, strerror(errno));
		return -1;
	}
	size_t n = fread(h, 1, sizeof h, f);
	fclose(f);
	if (n < sizeof h || memcmp(h, "\177ELF", 4) || h[4] != 1 || h[5] != 1 || h[18] != 83 ||
	    h[19] != 0) {
		set_error(m, "%s is not an AVR ELF (%s board)", path, BOARD[b->id]);
		return -1;
	}
	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(path, &fw) != 0 || !fw.flashsize) {
		set_error(m, "cannot load %s (%s board)", path, BOARD[b->id]);
		return -1;
	}
	if (fw.flashbase + fw.flashsize > FLASH_SIZE) {
		set_error(m, "%s needs %u bytes of flash, the ATmega162 has %d", path,
			  fw.flashbase + fw.flashsize, FLASH_SIZE);
		return -1;
	}
	if (fw.mmcu[0] && strcmp(fw.mmcu, "atmega162")) {
		set_error(m, "%s is built for %s, not atmega162", path, fw.mmcu);
		return -1;
	}
	avr_load_firmware(b->avr, &fw);
	b->avr->frequency = F_CPU;
	return 0;
}

static void set_board_record(avr_t *avr, int kind)
{
	uint8_t rec[4] = { BOARD_RECORD_MAGIC0, BOARD_RECORD_MAGIC1, (uint8_t)kind,
			   (uint8_t)(kind ^ 0xFF) };
	avr_eeprom_desc_t d = { .ee = rec, .offset = BOARD_RECORD_ADDR, .size = sizeof rec };
	avr_ioctl(avr, AVR_IOCTL_EEPROM_SET, &d);
}

static int board_setup(hbl_module_t *m, int id, const char *elf)
{
	board_t *b = &m->boards[id];
	b->m = m;
	b->id = id;
	b->avr = atmega162_new();
	if (!b->avr) {
		set_error(m, "out of memory");
		return -1;
	}
	if (load_elf(m, b, elf))
		return -1;
	avr_t *avr = b->avr;
	set_board_record(avr, id == COMM ? BOARD_KIND_COMM : BOARD_KIND_CONTROL);
	for (int n = 0; n < 2; n++) {
		line_t *l = &m->lines[id][n];
		l->rx = b;
		l->n = n;
		m->tx_ctx[id][n] = (tx_ctx_t){ m, id, n };
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0' + n),
						      UART_IRQ_OUTPUT), on_tx, &m->tx_ctx[id][n]);
		atmega162_after_read(avr, n ? M162_UDR1 : M162_UDR0, on_udr_read, l);
	}
	for (int p = 0; p < 5; p++) {
		m->port_ctx[id][p] = (port_ctx_t){ m, id, p };
		avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('A' + p),
						      IOPORT_IRQ_REG_PORT), on_port, &m->port_ctx[id][p]);
	}
	avr_cycle_timer_register(avr, HEARTBEAT, heartbeat, NULL);
	return 0;
}

/* --- the API (module_sim/simavr.py) --------------------------------------------------- */

int hbl_abi(void) { return HBL_ABI; }

size_t hbl_event_size(void) { return sizeof(hbl_event_t); }

void hbl_free(hbl_module_t *m)
{
	if (!m)
		return;
	for (int id = 0; id < 2; id++) {
		if (m->boards[id].avr) {
			avr_terminate(m->boards[id].avr);
			free(m->boards[id].avr);
		}
		for (int n = 0; n < 2; n++)
			free(m->lines[id][n].q);
	}
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
	set_dip(m->boards[CONTROL].avr, dip);
	set_switches(m->boards[COMM].avr, switches);
	return m;
}

const char *hbl_error(hbl_module_t *m) { return m->error; }

/* The module's time: the cycle the core behind has reached. */
uint64_t hbl_now(hbl_module_t *m)
{
	avr_cycle_count_t t = ~(avr_cycle_count_t)0;
	for (int i = 0; i < 2; i++)
		if (!m->boards[i].halted && m->boards[i].avr->cycle < t)
			t = m->boards[i].avr->cycle;
	if (t == ~(avr_cycle_count_t)0)	/* both halted: the later one's time */
		t = m->boards[0].avr->cycle > m->boards[1].avr->cycle ? m->boards[0].avr->cycle :
									  m->boards[1].avr->cycle;
	return t;
}

/* Run both cores until both have reached `until` (a cycle). 0, or -1 when a core crashed
 * (hbl_error names it); a core that sleeps with interrupts off halts (an EV_HALT event). */
int hbl_run(hbl_module_t *m, uint64_t until)
{
	for (;;) {
		board_t *b = NULL;
		for (int i = 0; i < 2; i++)
			if (!m->boards[i].halted &&
			    (!b || m->boards[i].avr->cycle < b->avr->cycle))
				b = &m->boards[i];
		if (!b || b->avr->cycle >= until)
			return 0;
		avr_flashaddr_t pc = b->avr->pc;
		int state = avr_run(b->avr);
		if (state == cpu_Done) {
			b->halted = 1;
			event(m, b->avr->cycle, EV_HALT, b->id, 0, 0, 0);
		} else if (state == cpu_Crashed || state == cpu_Stopped) {
			b->halted = 1;
			set_error(m, "%s board crashed at PC 0x%04x (byte address) after %.6f s",
				  BOARD[b->id], pc, b->avr->cycle / (double)F_CPU);
			return -1;
		}
	}
}

/* Stop a board for good (a test's board that never answers). */
void hbl_halt(hbl_module_t *m, int board)
{
	m->boards[board ? 1 : 0].halted = 1;
}

/* A byte into USART `uart` of `board` that ended (its stop bit) at cycle `end`, sent with
 * `bit` cycles a bit, `frame` cycles in all. */
void hbl_rx(hbl_module_t *m, int board, int uart, uint8_t byte, uint64_t end, uint32_t frame,
	    uint32_t bit)
{
	line_t *l = &m->lines[board ? 1 : 0][uart ? 1 : 0];
	line_push(l, byte, end > frame ? end - frame : 0, frame, bit);
}

/* The optical switches become `switches` at cycle `at` (at once if the comm core is past it). */
int hbl_switches_at(hbl_module_t *m, int switches, uint64_t at)
{
	avr_t *avr = m->boards[COMM].avr;
	if (at <= avr->cycle) {
		set_switches(avr, switches);
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
	return (uint32_t)atmega162_uart_frame_cycles(m->boards[board ? 1 : 0].avr, uart);
}

uint32_t hbl_bit_cycles(hbl_module_t *m, int board, int uart)
{
	return (uint32_t)atmega162_uart_bit_cycles(m->boards[board ? 1 : 0].avr, uart);
}

/* Receiver counters: overruns, bytes lost with the receiver off or the line full. */
unsigned long hbl_overruns(hbl_module_t *m)
{
	unsigned long n = 0;
	for (int i = 0; i < 4; i++)
		n += m->lines[i / 2][i % 2].overruns;
	return n;
}

/* ATmega162 for libsimavr 1.6: the part's memory map from avr-libc's iom162.h, simavr's
 * ports, UART receivers and EEPROM, plus what simavr cannot do for this part: the shared
 * UBRRH/UCSRC register, a double-buffered transmitter (UDR and the shift register), and
 * Timer0 in normal and CTC mode on the prescaler's grid (simavr 1.6 re-times a TCNT write
 * from the write instant and scales it by TOP instead of TOP+1, which would make the
 * 9.984 ms tick ~20 cycles off). */
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "sim_avr.h"
#include "sim_interrupts.h"
#include "sim_cycle_timers.h"
#include "sim_regbit.h"
#include "avr_eeprom.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "atmega162.h"

/* iom162.h, its SFR macros turned into plain data-space addresses (as simavr's cores do). */
#define _SFR_IO8(v) ((v) + 0x20)
#define _SFR_IO16(v) ((v) + 0x20)
#define _SFR_MEM8(v) (v)
#define _SFR_MEM16(v) (v)
#define _VECTOR(v) (v)
#define _BV(v) (1u << (v))
#define _AVR_IO_H_
#define __AVR_LIBC_DEPRECATED_ENABLE__
#include <avr/iom162.h>

_Static_assert(PORTA == M162_PORTA && PORTB == M162_PORTB && PORTC == M162_PORTC &&
	       PORTD == M162_PORTD && PORTE == M162_PORTE, "port addresses");
_Static_assert(UDR0 == M162_UDR0 && UDR1 == M162_UDR1, "UDR addresses");
_Static_assert(TIMER0_COMP_vect == M162_TIMER0_COMP_VECT &&
	       TIMER0_OVF_vect == M162_TIMER0_OVF_VECT, "Timer0 vectors");
_Static_assert(UBRR0H == UCSR0C && UBRR1H == UCSR1C, "shared UBRRH/UCSRC");
_Static_assert(_VECTORS_SIZE == 28 * 4, "28 vectors of 4 bytes");

#define M162_HOOKS 12

typedef struct m162_hook {
	avr_io_read_t r;		/* what owned the register before */
	void *rp;
	avr_io_write_t w;
	void *wp;
	atmega162_hook_t fn;
	void *param;
} m162_hook_t;

typedef struct m162_usart {
	avr_uart_t *uart;
	avr_io_addr_t r_ubrrl, r_shared, r_ucsra, r_ucsrb;
	uint8_t ubrrh, ucsrc;		/* the two registers behind one address */
	avr_cycle_count_t shared_read_at;
	avr_cycle_count_t bit, frame;
	avr_cycle_count_t shift_end;	/* the transmit shift register is busy until then */
	uint8_t udr, pending;		/* a byte waiting in UDR behind the shift register */
} m162_usart_t;

typedef struct m162_timer0 {
	uint32_t div;			/* CPU cycles per timer clock, 0 = stopped */
	avr_cycle_count_t base;		/* a timer-clock instant (maybe virtual) ... */
	uint8_t tcnt;			/* ... from which the counter holds this value */
	avr_cycle_count_t presc;	/* prescaler reset instant: clocks fall on presc + k*div */
	avr_cycle_count_t blocked;	/* clock at which a compare match is suppressed */
} m162_timer0_t;

typedef struct m162 {
	avr_t core;
	avr_io_t glue;			/* resets after the UARTs, so their defaults can be fixed */
	avr_eeprom_t eeprom;
	avr_ioport_t porta, portb, portc, portd, porte;
	avr_uart_t uart0, uart1;
	m162_usart_t usart[2];
	m162_timer0_t t0;
	avr_int_vector_t t0_ovf, t0_comp;
	m162_hook_t hooks[M162_HOOKS];
	int nhooks;
} m162_t;

#define M162(avr) ((m162_t *)(avr))

/* simavr's UART minus its baud registers (ubrrl/ubrrh/ucsz/usbs left empty on purpose:
 * its own baud code cannot see the shared register, so the frame length is set here). */
#define M162_USART_DECL(n) { \
	.name = '0' + n, \
	.r_udr = UDR##n, \
	.r_ucsra = UCSR##n##A, \
	.r_ucsrb = UCSR##n##B, \
	.fe = AVR_IO_REGBIT(UCSR##n##A, FE##n), \
	.dor = AVR_IO_REGBIT(UCSR##n##A, DOR##n), \
	.upe = AVR_IO_REGBIT(UCSR##n##A, UPE##n), \
	.u2x = AVR_IO_REGBIT(UCSR##n##A, U2X##n), \
	.txen = AVR_IO_REGBIT(UCSR##n##B, TXEN##n), \
	.rxen = AVR_IO_REGBIT(UCSR##n##B, RXEN##n), \
	.rxb8 = AVR_IO_REGBIT(UCSR##n##B, RXB8##n), \
	.ucsz2 = AVR_IO_REGBIT(UCSR##n##B, UCSZ##n##2), \
	.rxc = { .enable = AVR_IO_REGBIT(UCSR##n##B, RXCIE##n), \
		 .raised = AVR_IO_REGBIT(UCSR##n##A, RXC##n), \
		 .vector = USART##n##_RXC_vect, .raise_sticky = 1 }, \
	.txc = { .enable = AVR_IO_REGBIT(UCSR##n##B, TXCIE##n), \
		 .raised = AVR_IO_REGBIT(UCSR##n##A, TXC##n), \
		 .vector = USART##n##_TXC_vect }, \
	.udrc = { .enable = AVR_IO_REGBIT(UCSR##n##B, UDRIE##n), \
		  .raised = AVR_IO_REGBIT(UCSR##n##A, UDRE##n), \
		  .vector = USART##n##_UDRE_vect, .raise_sticky = 1 }, \
}

#define M162_PORT_DECL(L, c) { .name = c, .r_port = PORT##L, .r_ddr = DDR##L, .r_pin = PIN##L }

static void m162_init(avr_t *avr);

static const m162_t m162_template = {
	.core = {
		.mmcu = "atmega162",
		.ioend = RAMSTART - 1,
		.ramend = RAMEND,
		.flashend = FLASHEND,
		.e2end = E2END,
		.vector_size = 4,
		.signature = { SIGNATURE_0, SIGNATURE_1, SIGNATURE_2 },
		.fuse = { LFUSE_DEFAULT, HFUSE_DEFAULT, EFUSE_DEFAULT },
		.lockbits = 0xFF,
		.reset_flags = {
			.porf = AVR_IO_REGBIT(MCUCSR, PORF),
			.extrf = AVR_IO_REGBIT(MCUCSR, EXTRF),
			.borf = AVR_IO_REGBIT(MCUCSR, BORF),
			.wdrf = AVR_IO_REGBIT(MCUCSR, WDRF),
		},
		.init = m162_init,
	},
	AVR_EEPROM_DECLARE_NOEEPM(EE_RDY_vect),
	.porta = M162_PORT_DECL(A, 'A'),
	.portb = M162_PORT_DECL(B, 'B'),
	.portc = M162_PORT_DECL(C, 'C'),
	.portd = M162_PORT_DECL(D, 'D'),
	.porte = M162_PORT_DECL(E, 'E'),
	.uart0 = M162_USART_DECL(0),
	.uart1 = M162_USART_DECL(1),
	.t0_ovf = { .vector = TIMER0_OVF_vect, .enable = AVR_IO_REGBIT(TIMSK, TOIE0),
		    .raised = AVR_IO_REGBIT(TIFR, TOV0) },
	.t0_comp = { .vector = TIMER0_COMP_vect, .enable = AVR_IO_REGBIT(TIMSK, OCIE0),
		     .raised = AVR_IO_REGBIT(TIFR, OCF0) },
};

/* --- register hooks: wrap whatever handler simavr installed ------------------------ */

static uint8_t hook_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
	m162_hook_t *h = param;
	uint8_t v = h->r ? h->r(avr, addr, h->rp) : avr->data[addr];
	avr->data[addr] = v;
	h->fn(avr, addr, v, h->param);
	return v;
}

static void hook_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_hook_t *h = param;
	if (h->w)
		h->w(avr, addr, v, h->wp);
	else
		avr->data[addr] = v;
	h->fn(avr, addr, v, h->param);
}

static int hook_install(avr_t *avr, avr_io_addr_t addr, int on_read,
			atmega162_hook_t fn, void *param)
{
	m162_t *m = M162(avr);
	if (m->nhooks == M162_HOOKS || addr < 0x20 || addr > avr->ioend)
		return -1;
	m162_hook_t *h = &m->hooks[m->nhooks++];
	int io = AVR_DATA_TO_IO(addr);
	h->fn = fn;
	h->param = param;
	if (on_read) {
		h->r = avr->io[io].r.c;
		h->rp = avr->io[io].r.param;
		avr->io[io].r.c = hook_read;
		avr->io[io].r.param = h;
	} else {
		h->w = avr->io[io].w.c;
		h->wp = avr->io[io].w.param;
		avr->io[io].w.c = hook_write;
		avr->io[io].w.param = h;
	}
	return 0;
}

int atmega162_after_read(avr_t *avr, avr_io_addr_t addr, atmega162_hook_t fn, void *param)
{
	return hook_install(avr, addr, 1, fn, param);
}

int atmega162_after_write(avr_t *avr, avr_io_addr_t addr, atmega162_hook_t fn, void *param)
{
	return hook_install(avr, addr, 0, fn, param);
}

/* --- USARTs: the shared UBRRH/UCSRC register and the frame length ---------------- */

static void usart_update(avr_t *avr, m162_usart_t *u)
{
	uint8_t a = avr->data[u->r_ucsra], b = avr->data[u->r_ucsrb], c = u->ucsrc;
	unsigned ubrr = avr->data[u->r_ubrrl] | ((u->ubrrh & 0x0F) << 8);
	unsigned size = ((c >> UCSZ00) & 3) | (((b >> UCSZ02) & 1) << 2);
	unsigned data = size <= 3 ? 5 + size : size == 7 ? 9 : 8;	/* 4..6 reserved */
	unsigned parity = ((c >> UPM00) & 3) ? 1 : 0;
	unsigned stop = ((c >> USBS0) & 1) ? 2 : 1;

	u->bit = (avr_cycle_count_t)(ubrr + 1) * (((a >> U2X0) & 1) ? 8 : 16);
	u->frame = u->bit * (1 + data + parity + stop);
	u->uart->cycles_per_byte = u->frame;	/* simavr times RXC, TXC and UDRE with it */
}

static void usart_reg_changed(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_usart_t *u = param;
	(void)addr;
	(void)v;
	usart_update(avr, u);
	/* simavr raises UDRE when UDRIE is turned on unless its own transmitter is busy; ours
	 * may hold a byte in UDR (usart_udr_write) */
	if (u->pending && avr_regbit_get(avr, u->uart->udrc.raised)) {
		avr_clear_interrupt(avr, &u->uart->udrc);
		avr_regbit_clear(avr, u->uart->udrc.raised);
	}
}

static void usart_ubrrl_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	avr_core_watch_write(avr, addr, v);
	usart_update(avr, param);
}

/* URSEL (bit 7) picks the register on a write. */
static void usart_shared_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_usart_t *u = param;
	if (v & 0x80)
		u->ucsrc = v & 0x7F;
	else
		u->ubrrh = v & 0x0F;
	avr_core_watch_write(avr, addr, u->ubrrh);
	usart_update(avr, u);
}

/* A read gives UBRRH, a second read on the very next cycle gives UCSRC (datasheet). */
static uint8_t usart_shared_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
	(void)addr;
	m162_usart_t *u = param;
	uint8_t v = avr->cycle == u->shared_read_at + 1 ? (0x80 | u->ucsrc) : u->ubrrh;
	u->shared_read_at = avr->cycle;
	return v;
}

/* The transmitter, double-buffered as on the chip: simavr 1.6 keeps UDRE low for a whole
 * frame after every write, so a program that waits for UDRE would fall one frame behind
 * the chip on every burst. Here a byte written while the shift register is idle starts at
 * once and UDR is free again at once; one written while it is busy waits in UDR (UDRE low)
 * until the shift register takes it, and a write while UDRE is low is lost. UART_IRQ_OUTPUT
 * is raised when a byte's start bit begins. */
static void usart_tx_start(avr_t *avr, m162_usart_t *u, uint8_t v, avr_cycle_count_t now)
{
	u->shift_end = now + u->frame;
	avr_raise_irq(u->uart->io.irq + UART_IRQ_OUTPUT, v);
	avr_raise_interrupt(avr, &u->uart->udrc);
}

static avr_cycle_count_t usart_tx_timer(avr_t *avr, avr_cycle_count_t when, void *param)
{
	m162_usart_t *u = param;
	if (u->pending) {
		u->pending = 0;
		usart_tx_start(avr, u, u->udr, when);
		return u->shift_end;
	}
	avr_raise_interrupt(avr, &u->uart->txc);	/* shift register and UDR empty */
	return 0;
}

static void usart_udr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_usart_t *u = param;
	avr_uart_t *p = u->uart;
	(void)addr;
	if (!avr_regbit_get(avr, p->txen) || u->pending)
		return;	/* with UDRE low the chip ignores the write (datasheet, UDRn) */
	if (avr_regbit_get(avr, p->udrc.raised)) {
		avr_clear_interrupt(avr, &p->udrc);
		avr_regbit_clear(avr, p->udrc.raised);	/* UDRE is sticky: clear the flag too */
	}
	if (avr->cycle >= u->shift_end && !u->pending) {
		usart_tx_start(avr, u, v, avr->cycle);
		avr_cycle_timer_register(avr, u->frame, usart_tx_timer, u);
	} else {
		u->udr = v;
		u->pending = 1;
	}
}

avr_uart_t *atmega162_uart(avr_t *avr, int n)
{
	return M162(avr)->usart[n ? 1 : 0].uart;
}

avr_cycle_count_t atmega162_uart_bit_cycles(avr_t *avr, int n)
{
	return M162(avr)->usart[n ? 1 : 0].bit;
}

avr_cycle_count_t atmega162_uart_frame_cycles(avr_t *avr, int n)
{
	return M162(avr)->usart[n ? 1 : 0].frame;
}

/* --- Timer0 ------------------------------------------------------------------------ */

static const uint16_t t0_divs[8] = { 0, 1, 8, 64, 256, 1024, 0, 0 };	/* 6, 7: T0 pin */

static unsigned t0_top(avr_t *avr)
{
	uint8_t r = avr->data[TCCR0];
	int ctc = (r & _BV(WGM01)) && !(r & _BV(WGM00));
	return ctc ? avr->data[OCR0] : 0xFF;
}

/* Counter value k timer clocks after holding v.  In CTC a value above TOP (OCR0 lowered
 * under the counter) runs on to 0xFF and wraps, as on the chip. */
static uint8_t t0_advance(avr_t *avr, unsigned v, uint64_t k)
{
	unsigned top = t0_top(avr);
	if (v > top) {
		if (k < 256u - v)
			return (uint8_t)(v + k);
		k -= 256u - v;
		v = 0;
	}
	return (uint8_t)((v + k) % (top + 1));
}

/* Timer clocks until the counter leaves value x (a flag is set on that clock), 0 = never. */
static uint64_t t0_clocks_to_leave(avr_t *avr, unsigned v, unsigned x)
{
	unsigned top = t0_top(avr);
	if (v > top) {
		if (x >= v)
			return x - v + 1;
		return x <= top ? (256u - v) + x + 1 : 0;
	}
	if (x > top)
		return 0;
	return (x + top + 1 - v) % (top + 1) + 1;
}

/* Move the base to the last timer clock at or before now. */
static void t0_sync(m162_t *m)
{
	avr_t *avr = &m->core;
	m162_timer0_t *t = &m->t0;
	if (!t->div || avr->cycle < t->base)
		return;
	uint64_t k = (avr->cycle - t->base) / t->div;
	t->tcnt = t0_advance(avr, t->tcnt, k);
	t->base += k * t->div;
}

static avr_cycle_count_t t0_next(m162_t *m)
{
	avr_t *avr = &m->core;
	m162_timer0_t *t = &m->t0;
	if (!t->div)
		return 0;
	uint64_t a = t0_clocks_to_leave(avr, t->tcnt, 0xFF);
	uint64_t b = t0_clocks_to_leave(avr, t->tcnt, avr->data[OCR0]);
	uint64_t k = !a ? b : !b ? a : a < b ? a : b;
	return k ? t->base + k * t->div : 0;
}

static avr_cycle_count_t t0_fire(avr_t *avr, avr_cycle_count_t when, void *param)
{
	m162_t *m = param;
	m162_timer0_t *t = &m->t0;
	if (!t->div || when <= t->base)
		return 0;
	uint64_t k = (when - t->base) / t->div;
	uint8_t left = t0_advance(avr, t->tcnt, k - 1);
	t->tcnt = t0_advance(avr, t->tcnt, k);
	t->base = t->base + k * t->div;
	if (left == 0xFF)
		avr_raise_interrupt(avr, &m->t0_ovf);
	if (left == avr->data[OCR0] && t->base != t->blocked)
		avr_raise_interrupt(avr, &m->t0_comp);
	return t0_next(m);
}

static void t0_reschedule(m162_t *m)
{
	avr_t *avr = &m->core;
	avr_cycle_timer_cancel(avr, t0_fire, m);
	avr_cycle_count_t at = t0_next(m);
	if (at)
		avr_cycle_timer_register(avr, at > avr->cycle ? at - avr->cycle : 0, t0_fire, m);
}

static avr_cycle_count_t t0_clock_at_or_before(m162_timer0_t *t, avr_cycle_count_t c)
{
	return t->presc + (c - t->presc) / t->div * t->div;
}

static uint8_t t0_tcnt_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
	(void)addr;
	m162_t *m = param;
	t0_sync(m);
	return avr->data[TCNT0] = m->t0.tcnt;
}

/* The prescaler runs on: the written value is counted up on the next timer clock, and
 * that clock cannot raise a compare match. */
static void t0_tcnt_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	m162_timer0_t *t = &m->t0;
	avr_core_watch_write(avr, addr, v);
	t->tcnt = v;
	if (t->div) {
		t->base = t0_clock_at_or_before(t, avr->cycle);
		t->blocked = t->base + t->div;
	}
	t0_reschedule(m);
}

static void t0_tccr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	m162_timer0_t *t = &m->t0;
	t0_sync(m);
	avr_core_watch_write(avr, addr, v & ~_BV(FOC0));	/* FOC0 is a strobe */
	t->div = t0_divs[v & 7];
	if (t->div)
		t->base = t0_clock_at_or_before(t, avr->cycle);
	else if ((v & 7) >= 6)
		AVR_LOG(avr, LOG_WARNING, "TIMER0: external clock on T0 not modelled\n");
	t0_reschedule(m);
}

static void t0_ocr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	t0_sync(m);
	avr_core_watch_write(avr, addr, v);
	t0_reschedule(m);
}

/* PSR310 restarts the prescaler shared by Timer0 and Timer1. */
static void t0_sfior_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	m162_timer0_t *t = &m->t0;
	if (v & _BV(PSR310)) {
		t0_sync(m);
		t->presc = avr->cycle;
		if (t->div)
			t->base = avr->cycle;
		t0_reschedule(m);
	}
	avr_core_watch_write(avr, addr, v & ~_BV(PSR310));
}

/* simavr only queues an interrupt whose enable bit is set when the flag rises, so an
 * enable written over a flag that is already up has to be raised here. */
static void t0_timsk_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	avr_core_watch_write(avr, addr, v);
	avr_int_vector_t *vs[2] = { &m->t0_ovf, &m->t0_comp };
	for (int i = 0; i < 2; i++)
		if (avr_regbit_get(avr, vs[i]->enable) && avr_regbit_get(avr, vs[i]->raised))
			avr_raise_interrupt(avr, vs[i]);
}

/* Flags clear by writing a one. */
static void t0_tifr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	m162_t *m = param;
	avr_int_vector_t *vs[2] = { &m->t0_ovf, &m->t0_comp };
	for (int i = 0; i < 2; i++) {
		uint8_t mask = 1u << vs[i]->raised.bit;
		if ((v & mask) && avr_regbit_get(avr, vs[i]->raised))
			avr_clear_interrupt(avr, vs[i]);
	}
	uint8_t others = v & ~(_BV(TOV0) | _BV(OCF0));
	avr_core_watch_write(avr, addr, avr->data[addr] & ~others);
}

/* --- init and reset ---------------------------------------------------------------- */

static void m162_glue_reset(avr_io_t *io)
{
	m162_t *m = (m162_t *)((char *)io - offsetof(m162_t, glue));
	avr_t *avr = &m->core;
	for (int n = 0; n < 2; n++) {
		m162_usart_t *u = &m->usart[n];
		u->ubrrh = 0;
		u->ucsrc = _BV(UCSZ01) | _BV(UCSZ00);	/* 8N1 at reset */
		u->shared_read_at = ~(avr_cycle_count_t)0 - 1;
		u->shift_end = 0;
		u->pending = 0;
		avr->data[u->r_ucsrb] = 0;		/* simavr's reset turns TXEN on */
		usart_update(avr, u);
	}
	memset(&m->t0, 0, sizeof m->t0);
	m->t0.blocked = ~(avr_cycle_count_t)0;
}

static void m162_init(avr_t *avr)
{
	m162_t *m = M162(avr);
	static const avr_io_t glue = { .kind = "m162", .reset = m162_glue_reset };

	m->glue = glue;
	avr_register_io(avr, &m->glue);	/* first registered, last reset */
	avr_eeprom_init(avr, &m->eeprom);
	avr_ioport_init(avr, &m->porta);
	avr_ioport_init(avr, &m->portb);
	avr_ioport_init(avr, &m->portc);
	avr_ioport_init(avr, &m->portd);
	avr_ioport_init(avr, &m->porte);
	avr_uart_init(avr, &m->uart0);
	avr_uart_init(avr, &m->uart1);
	m->uart0.flags = m->uart1.flags = 0;	/* no usleep() on polling, no console echo */

	static const avr_io_addr_t regs[2][4] = {
		{ UBRR0L, UBRR0H, UCSR0A, UCSR0B },
		{ UBRR1L, UBRR1H, UCSR1A, UCSR1B },
	};
	for (int n = 0; n < 2; n++) {
		m162_usart_t *u = &m->usart[n];
		u->uart = n ? &m->uart1 : &m->uart0;
		u->r_ubrrl = regs[n][0];
		u->r_shared = regs[n][1];
		u->r_ucsra = regs[n][2];
		u->r_ucsrb = regs[n][3];
		avr_register_io_write(avr, u->r_ubrrl, usart_ubrrl_write, u);
		avr_register_io_write(avr, u->r_shared, usart_shared_write, u);
		avr_register_io_read(avr, u->r_shared, usart_shared_read, u);
		hook_install(avr, u->r_ucsra, 0, usart_reg_changed, u);	/* U2X */
		hook_install(avr, u->r_ucsrb, 0, usart_reg_changed, u);	/* UCSZ2 */
		/* our transmitter instead of simavr's (its UDR read, the receiver, stays) */
		avr->io[AVR_DATA_TO_IO(n ? UDR1 : UDR0)].w.c = usart_udr_write;
		avr->io[AVR_DATA_TO_IO(n ? UDR1 : UDR0)].w.param = u;
	}

	avr_register_vector(avr, &m->t0_ovf);
	avr_register_vector(avr, &m->t0_comp);
	avr_register_io_write(avr, TCCR0, t0_tccr_write, m);
	avr_register_io_write(avr, TCNT0, t0_tcnt_write, m);
	avr_register_io_read(avr, TCNT0, t0_tcnt_read, m);
	avr_register_io_write(avr, OCR0, t0_ocr_write, m);
	avr_register_io_write(avr, SFIOR, t0_sfior_write, m);
	avr_register_io_write(avr, TIMSK, t0_timsk_write, m);
	avr_register_io_write(avr, TIFR, t0_tifr_write, m);
}

static void m162_sleep_none(avr_t *avr, avr_cycle_count_t how_long)
{
	(void)avr;
	(void)how_long;
}

avr_t *atmega162_new(void)
{
	avr_t *avr = avr_core_allocate(&m162_template.core, sizeof(m162_t));
	if (!avr)
		return NULL;
	avr_init(avr);
	avr->frequency = 1000000;
	avr->sleep = m162_sleep_none;
	return avr;
}

avr_io_addr_t atmega162_port_addr(char letter)
{
	switch (letter) {
	case 'A': return PORTA;
	case 'B': return PORTB;
	case 'C': return PORTC;
	case 'D': return PORTD;
	case 'E': return PORTE;
	default: return 0;
	}
}

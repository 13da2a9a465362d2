/* Lines: frames into a USART receiver (receiver.h). */
#include <stdlib.h>

#include "sim_cycle_timers.h"
#include "sim_interrupts.h"
#include "sim_regbit.h"
#include "avr_uart.h"
#include "atmega162.h"
#include "receiver.h"

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
	return 0;		/* line_service registers the next wake itself */
}

static void line_pop(line_t *l)
{
	l->head = (l->head + 1) % l->cap;
	l->len--;
}

/* Hand a frame to simavr (with FE set when the sender's bit time is more than 4 % off). */
static void line_deliver(line_t *l, frame_t *f)
{
	avr_t *avr = l->avr;
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

/* 1 when the gate drops the frame (counted in `gated`). */
static int line_gated(line_t *l, const frame_t *f, int whole)
{
	if (l->gate(l, f, whole))
		return 0;
	l->gated++;
	return 1;
}

static void line_service(line_t *l)
{
	avr_t *avr = l->avr;
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
			if (l->gate && line_gated(l, f, 0)) {
				line_pop(l);
				continue;
			}
			f->state = F_SHIFT;
		}
		if (f->state == F_SHIFT && l->gate) {
			/* the gate decides at the frame's end */
			if (now < f->end) {
				wake = f->end;
				break;
			}
			if (line_gated(l, f, 1)) {
				line_pop(l);
				continue;
			}
			if (!n) {
				line_deliver(l, f);
				line_pop(l);
				continue;
			}
			f->state = F_HELD;
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
			if (l->overrun)
				l->overrun(l, next->start, f->value);
			line_pop(l);
			continue;
		}
		wake = next ? next->start : 0;	/* else a read of UDR calls us */
		break;
	}

	/* RXC: up at the end of the newest byte, or at once for an older one (simavr may
	 * have dropped it after two fast reads, or be about to raise it a frame late). */
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

void line_push(line_t *l, uint8_t value, avr_cycle_count_t at, avr_cycle_count_t frame,
	       avr_cycle_count_t bit)
{
	if (l->len >= LINE_MAX_QUEUE) {
		l->full++;
		return;
	}
	if (l->len == l->cap) {
		size_t cap = l->cap ? 2 * l->cap : 64;
		frame_t *q = malloc(cap * sizeof *q);
		if (!q)
			hexbot_out_of_memory();
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
	line_service(l);	/* a new frame may be due now, or end a held one (overrun) */
}

static void on_udr_read(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
	(void)avr;
	(void)addr;
	(void)v;
	line_service(param);
}

void line_attach(line_t *l, avr_t *avr, int board, int n)
{
	l->avr = avr;
	l->board = board;
	l->n = n;
	atmega162_after_read(avr, n ? M162_UDR1 : M162_UDR0, on_udr_read, l);
}

void line_free(line_t *l)
{
	free(l->q);
	l->q = NULL;
	l->cap = l->head = l->len = 0;
}

/* Self-test image for the simavr harness; the same ELF runs on both boards.
 *
 * Timer0: prescaler 64, TCNT0 reloaded to 0x64 in the overflow ISR (9.984 ms), counting
 * ticks and toggling PD7; after 'c', the same from CTC mode (OCR0 = 155, the compare-match
 * interrupt, no reload), as the HexBot images run it.  USART0 at UBRR 12, USART1 at UBRR
 * 207 (8N1, UCSRnC written with URSEL), received by interrupt, sent by polling UDRE.
 * PORTA selects the centre IR transceiver (PA1), PORTE = 0x05.  A byte b on USART1 is
 * answered on USART1 with
 *   't' the tick counter's low byte   'd' PINC   'w' PINB   'b' "xyz" back to back
 *   'a' PINA   'p' PIND   'c' Timer0 to CTC mode, answered with TCNT0
 *   's' PORTA to side channel 1 (PA2), 'S' sent there, back to centre 10 ticks later
 *       with 'C'
 *   'X' a write outside RAM (simavr stops the core: the harness reports a crash)
 *   anything else: b + 1
 * and then passed on to USART0.  A byte on USART0 is sent to USART1 ('d' and 'w' answered
 * as above), so the control board shows on its debug port what the comm board forwards. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>

#define RING 32
typedef struct {
	volatile uint8_t buf[RING];
	volatile uint8_t head, tail;
} ring_t;

static ring_t rx0, rx1;
static volatile uint8_t ticks;

#define CENTRE _BV(PA1)
#define SIDE1 _BV(PA2)

ISR(TIMER0_OVF_vect)
{
	TCNT0 = 0x64;
	ticks++;
	PORTD ^= _BV(PD7);
}

ISR(TIMER0_COMP_vect)
{
	ticks++;
	PORTD ^= _BV(PD7);
}

static void put(ring_t *r, uint8_t b)
{
	uint8_t h = (uint8_t)((r->head + 1) % RING);
	if (h != r->tail) {
		r->buf[r->head] = b;
		r->head = h;
	}
}

ISR(USART0_RXC_vect) { put(&rx0, UDR0); }
ISR(USART1_RXC_vect) { put(&rx1, UDR1); }

static int get(ring_t *r)
{
	if (r->head == r->tail)
		return -1;
	uint8_t b = r->buf[r->tail];
	r->tail = (uint8_t)((r->tail + 1) % RING);
	return b;
}

static void tx0(uint8_t b)
{
	while (!(UCSR0A & _BV(UDRE0)))
		;
	UDR0 = b;
}

static void tx1(uint8_t b)
{
	while (!(UCSR1A & _BV(UDRE1)))
		;
	UDR1 = b;
}

int main(void)
{
	uint8_t side = 0, side_at = 0;
	int b;

	DDRA = 0x07;
	PORTA = CENTRE;
	DDRD = _BV(PD7);
	DDRE = 0x07;
	PORTE = 0x05;

	UBRR0H = 0;
	UBRR0L = 12;
	UCSR0C = _BV(URSEL0) | _BV(UCSZ01) | _BV(UCSZ00);
	UCSR0B = _BV(RXEN0) | _BV(TXEN0) | _BV(RXCIE0);
	UBRR1H = 0;
	UBRR1L = 207;
	UCSR1C = _BV(URSEL1) | _BV(UCSZ11) | _BV(UCSZ10);
	UCSR1B = _BV(RXEN1) | _BV(TXEN1) | _BV(RXCIE1);

	TCNT0 = 0x64;
	TCCR0 = _BV(CS01) | _BV(CS00);
	TIMSK = _BV(TOIE0);
	set_sleep_mode(SLEEP_MODE_IDLE);
	sei();

	for (;;) {
		while ((b = get(&rx1)) >= 0) {
			switch (b) {
			case 't': tx1(ticks); break;
			case 'd': tx1(PINC); break;
			case 'w': tx1(PINB); break;
			case 'a': tx1(PINA); break;
			case 'p': tx1(PIND); break;
			case 'c':
				OCR0 = 155;
				TCCR0 = _BV(WGM01) | _BV(CS01) | _BV(CS00);
				TIMSK = _BV(OCIE0);
				tx1(TCNT0);
				break;
			case 'b': tx1('x'); tx1('y'); tx1('z'); break;
			case 's':
				PORTA = SIDE1;
				tx1('S');
				side = 1;
				side_at = ticks;
				break;
			case 'X': *(volatile uint8_t *)0x2000 = 1; break;
			default: tx1((uint8_t)(b + 1));
			}
			tx0((uint8_t)b);
		}
		while ((b = get(&rx0)) >= 0)
			tx1(b == 'd' ? PINC : b == 'w' ? PINB : (uint8_t)b);
		if (side && (uint8_t)(ticks - side_at) >= 10) {
			side = 0;
			PORTA = CENTRE;
			tx1('C');
		}
		cli();
		if (rx0.head == rx0.tail && rx1.head == rx1.tail && !side) {
			sleep_enable();
			sei();
			sleep_cpu();	/* SEI's one-instruction delay: no wake-up is missed */
			sleep_disable();
		}
		sei();
	}
}

/* The board layer on the ATmega162 at 1 MHz: ports A..E, USART0 and USART1 (8N1, polled
 * like the thesis's ReceiveByte/TransmitByte, so a byte the program does not read waits in
 * the two-byte FIFO and the third overruns exactly as on the chip), a background transmit
 * queue emptied by the UDRE interrupt, the 10 ms Timer0 tick, and the board-kind guard:
 * an image that finds another board's record in the EEPROM drives no pin. */
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/atomic.h>
#include <util/delay.h>

#include "hexbot.h"

#if F_CPU != HEXBOT_F_CPU
#error "F_CPU must match bus/ (hexbot_gen.h)"
#endif

/* Timer0 in CTC mode clears itself on the compare match: the tick grid is the hardware's,
 * whatever the interrupt latency (a TCNT0 reload in the ISR lost a count whenever the ISR
 * came 64 cycles late). */
static volatile uint16_t ticks;

static volatile uint8_t woken; /* an interrupt came since the step began (board_idle) */
ISR(TIMER0_COMP_vect) { ticks++; woken = 1; }

/* What the program found in this step (board_idle): a byte read, a full UDR (bit = UART). */
static uint8_t rx_read, tx_blocked;

/* --- background transmit queue (the v2 actuator reports) ---
 * One ring per UART: the program writes head, the UDRE interrupt tail (single-byte stores,
 * atomic on the AVR), so the program never turns interrupts off for it. */
#define QUEUE 32
#define QMASK (QUEUE - 1)
#if QUEUE & QMASK
#error "QUEUE must be a power of two"
#endif
static volatile uint8_t queue[2][QUEUE], head[2], tail[2];

static void udre_enable(uint8_t uart, uint8_t on)
{
    if (uart == UART0)
        UCSR0B = on ? (UCSR0B | _BV(UDRIE0)) : (UCSR0B & ~_BV(UDRIE0));
    else
        UCSR1B = on ? (UCSR1B | _BV(UDRIE1)) : (UCSR1B & ~_BV(UDRIE1));
}

/* The UDRE interrupt: itself off and the others on while it works, so the tick waits for
 * no more than its prologue or epilogue (a whole UDRE handler, ~60 cycles, came close to
 * one Timer0 count); the program cannot run before it returns, so the ring is its own. */
static inline __attribute__((always_inline)) void drain(uint8_t uart)
{
    udre_enable(uart, 0);
    sei();
    uint8_t t = tail[uart];
    if (head[uart] != t) {
        uint8_t b = queue[uart][t];
        tail[uart] = t = (uint8_t)((t + 1) & QMASK);
        if (uart == UART0)
            UDR0 = b;
        else
            UDR1 = b;
    }
    cli();
    if (head[uart] != t)
        udre_enable(uart, 1);
    woken = 1;
}

ISR(USART0_UDRE_vect) { drain(UART0); }
ISR(USART1_UDRE_vect) { drain(UART1); }

uint8_t board_tx_queue(uint8_t uart, const uint8_t *data, uint8_t n)
{
    uint8_t h = head[uart];
    if ((uint8_t)((h - tail[uart]) & QMASK) + n >= QUEUE)
        return 0; /* a tail that moves on meanwhile only frees more room */
    for (uint8_t k = 0; k < n; k++) {
        queue[uart][h] = data[k];
        h = (uint8_t)((h + 1) & QMASK);
    }
    head[uart] = h; /* the bytes are in before the interrupt can see them */
    udre_enable(uart, 1);
    return 1;
}

/* --- ports --- */
static volatile uint8_t *const PORT[5] = {&PORTA, &PORTB, &PORTC, &PORTD, &PORTE};
static volatile uint8_t *const DDR[5] = {&DDRA, &DDRB, &DDRC, &DDRD, &DDRE};
static volatile uint8_t *const PIN[5] = {&PINA, &PINB, &PINC, &PIND, &PINE};

uint8_t board_port(uint8_t port) { return *PORT[port]; }
void board_port_write(uint8_t port, uint8_t value) { *PORT[port] = value; }
uint8_t board_pins(uint8_t port) { return *PIN[port]; }

uint16_t board_ticks(void)
{
    uint16_t t;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { t = ticks; }
    return t;
}

uint8_t board_tick_reached(uint16_t target)
{
    return (int16_t)(board_ticks() - target) >= 0;
}

/* --- UARTs --- */
uint8_t board_rx_ready(uint8_t uart)
{
    return uart == UART0 ? (UCSR0A & _BV(RXC0)) != 0 : (UCSR1A & _BV(RXC1)) != 0;
}

uint8_t board_rx_read(uint8_t uart)
{
    rx_read |= (uint8_t)(1 << uart);
    return uart == UART0 ? UDR0 : UDR1;
}

uint8_t board_tx_ready(uint8_t uart)
{
    if (head[uart] != tail[uart])
        return 0; /* the program's bytes go after what is queued */
    uint8_t ready = uart == UART0 ? (UCSR0A & _BV(UDRE0)) != 0 : (UCSR1A & _BV(UDRE1)) != 0;
    if (!ready)
        tx_blocked |= (uint8_t)(1 << uart);
    return ready;
}

void board_tx_write(uint8_t uart, uint8_t byte)
{
    if (uart == UART0)
        UDR0 = byte;
    else
        UDR1 = byte;
}

uint8_t board_tx_some(uint8_t uart, const uint8_t *data, uint8_t flash, uint8_t k, uint8_t len)
{
    while (k < len && board_tx_ready(uart)) {
        board_tx_write(uart, flash ? pgm_read_byte(&data[k]) : data[k]);
        k++;
    }
    return k;
}

void board_init(const uint8_t outputs[5], const uint8_t pullups[5])
{
    for (uint8_t p = 0; p < 5; p++)
        *DDR[p] = outputs[p], *PORT[p] = pullups[p];
    /* 8N1; UBRRH and UCSRC share an address on this part: URSEL picks UCSRC */
    UBRR0H = 0;
    UBRR0L = UART0_UBRR;
    UCSR0C = _BV(URSEL0) | _BV(UCSZ01) | _BV(UCSZ00);
    UCSR0B = _BV(RXEN0) | _BV(TXEN0);
    UBRR1H = 0;
#if defined(HEXBOT_COMM)
    UBRR1L = IR_UBRR; /* the comm board's UART1 is the IR link */
#else
    UBRR1L = DEBUG_UBRR; /* the control board's UART1 is the debug terminal */
#endif
    UCSR1C = _BV(URSEL1) | _BV(UCSZ11) | _BV(UCSZ10);
    UCSR1B = _BV(RXEN1) | _BV(TXEN1);
    /* Timer0 runs since power-up (timer_at_power_up); its tick from now on */
    TIMSK |= _BV(OCIE0);
    set_sleep_mode(SLEEP_MODE_IDLE); /* SLEEP runs only in board_idle: SE stays set */
    sleep_enable();
    sei();
}

/* Start Timer0 before the C runtime clears .bss and copies .data (about a millisecond at
 * 1 MHz), so its tick grid starts at power-up as in the model: CTC, prescaler 64, counts
 * 0..TIMER0_TOP = 156 counts = 9.984 ms. Its interrupt is enabled in board_init. */
__attribute__((naked, used, section(".init3"))) static void timer_at_power_up(void)
{
    OCR0 = TIMER0_TOP;
    TCCR0 = _BV(WGM01) | _BV(CS01) | _BV(CS00);
}

/* --- the board-kind guard (bus/chip.py) --- */
#if defined(HEXBOT_COMM)
#define OWN_KIND BOARD_KIND_COMM
#define OTHER_KIND BOARD_KIND_CONTROL
#define OWN_UBRR1 IR_UBRR      /* UART1 of the comm board: the IR link */
#define OTHER_UBRR1 DEBUG_UBRR /* ... of the control board: the debug terminal */
static const char GUARD_OTHER[] PROGMEM = TXT_GUARD_COMM_ON_CONTROL;
static const char GUARD_NONE[] PROGMEM = TXT_GUARD_COMM_ON_NONE;
#else
#define OWN_KIND BOARD_KIND_CONTROL
#define OTHER_KIND BOARD_KIND_COMM
#define OWN_UBRR1 DEBUG_UBRR
#define OTHER_UBRR1 IR_UBRR
static const char GUARD_OTHER[] PROGMEM = TXT_GUARD_CONTROL_ON_COMM;
static const char GUARD_NONE[] PROGMEM = TXT_GUARD_CONTROL_ON_NONE;
#endif

static uint8_t eeprom_byte(uint8_t addr)
{
    loop_until_bit_is_clear(EECR, EEWE);
    EEAR = addr;
    EECR |= _BV(EERE);
    return EEDR;
}

/* The kind the EEPROM record names: "HB", kind, kind ^ 0xFF; 0 for none (erased, damaged). */
static uint8_t board_kind(void)
{
    if (eeprom_byte(BOARD_RECORD_ADDR) != BOARD_RECORD_MAGIC0 ||
        eeprom_byte(BOARD_RECORD_ADDR + 1) != BOARD_RECORD_MAGIC1)
        return 0;
    uint8_t kind = eeprom_byte(BOARD_RECORD_ADDR + 2);
    return (uint8_t)(kind ^ eeprom_byte(BOARD_RECORD_ADDR + 3)) == 0xFF ? kind : 0;
}

/* Not this image's board: every pin stays an input without pull-up (DDR and PORT as at
 * reset); only UART1's transmitter runs (it takes over TXD1), at the baud of the board the
 * record names, and says so about once a second, forever. */
__attribute__((noreturn)) static void wrong_board(uint8_t kind)
{
    const char *text = GUARD_NONE;
    UBRR1L = OWN_UBRR1;
    if (kind == OTHER_KIND) {
        text = GUARD_OTHER;
        UBRR1L = OTHER_UBRR1;
    }
    UCSR1B = _BV(TXEN1); /* UCSR1C is 8N1 at reset */
    for (;;) {
        for (const char *p = text; pgm_read_byte(p); p++) {
            loop_until_bit_is_set(UCSR1A, UDRE1);
            UDR1 = pgm_read_byte(p);
        }
        _delay_ms(1000);
    }
}

/* --- idle between steps ---
 * program_step() returns when the program waits for a tick, a received byte or a free UDR.
 * Until one of those comes the CPU sleeps in Idle mode (the timer and the USARTs run on),
 * woken by an interrupt: Timer0's tick (always on), a received byte (RXCIE, on for one
 * wake-up: its handler turns it off and leaves the byte to the program's polling), UDR free
 * again after a byte the program wrote (UDRIE, on only while UDRE is low; drain() turns it
 * off when the background queue is empty). Whatever came during the step itself (an
 * interrupt, a byte, a free UDR the program had found busy) runs the step again instead.
 * Power saving on the chip; in simavr a sleeping core costs nothing, so a fleet of them
 * runs faster than real time. The pins are not an interrupt source: an optical switch or a
 * DIP change is seen at the next tick at the latest. */
static uint8_t rx_at_step;     /* RXC of each UART (bit = UART) when the step began */

ISR(USART0_RXC_vect) { UCSR0B &= ~_BV(RXCIE0); woken = 1; }
ISR(USART1_RXC_vect) { UCSR1B &= ~_BV(RXCIE1); woken = 1; }

static uint8_t rxc_bits(void)
{
    return (uint8_t)(((UCSR0A & _BV(RXC0)) ? 1 : 0) | ((UCSR1A & _BV(RXC1)) ? 2 : 0));
}

static uint8_t udre_bits(void)
{
    return (uint8_t)(((UCSR0A & _BV(UDRE0)) ? 1 : 0) | ((UCSR1A & _BV(UDRE1)) ? 2 : 0));
}

static void board_step(void)
{
    woken = 0;
    rx_read = 0;
    tx_blocked = 0;
    rx_at_step = rxc_bits();
    program_step();
}

static void board_idle(void)
{
    uint8_t rx = rxc_bits(), udre = udre_bits();
    /* a byte that came during the step (or after one the program read), a UDR the program
     * found busy and that is free now: the step may have looked too early */
    if ((rx & (uint8_t)(rx_read | ~rx_at_step)) || (tx_blocked & udre))
        return;
    /* each a single SBI: no interrupt can come between read and write */
    if (!(rx & 1))
        UCSR0B |= _BV(RXCIE0);
    if (!(rx & 2))
        UCSR1B |= _BV(RXCIE1);
    if (!(udre & 1))
        UCSR0B |= _BV(UDRIE0);
    if (!(udre & 2))
        UCSR1B |= _BV(UDRIE1);
    /* interrupts off only for the test: a tick is never held up more than a few cycles */
    cli();
    if (woken) {
        sei();
        return;
    }
    sei(); /* the instruction after SEI runs before any interrupt: no wake-up is lost */
    sleep_cpu();
}

int main(void)
{
    uint8_t kind = board_kind();
    if (kind != OWN_KIND)
        wrong_board(kind);
    board_init(program_outputs, program_pullups);
    for (;;) {
        board_step();
        board_idle();
    }
}

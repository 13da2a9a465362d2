/* An ATmega162 core for libsimavr 1.6, which has none.
 *
 * What is modelled: 16 KiB flash, 1 KiB SRAM at 0x100 (RAMEND 0x4FF), 512 B EEPROM,
 * ports A..E, USART0/USART1 (simavr's UART, with the shared UBRRH/UCSRC register and a
 * frame length that follows UBRR, U2X and UCSRC), Timer0 (overflow and compare flags in
 * normal, CTC and fast-PWM mode, a free-running prescaler; phase-correct PWM counts as
 * normal mode; no OC0 pin), 28 vectors of 4 bytes.  Not modelled:
 * Timer1/2/3, SPI, the watchdog, external interrupts, pin-change interrupts, XMEM.
 * Registers of missing peripherals read back what was written. */
#ifndef ATMEGA162_H
#define ATMEGA162_H

#include "sim_avr.h"
#include "avr_uart.h"

/* Data-space addresses the harness needs (checked against avr-libc's iom162.h). */
enum {
	M162_PORTA = 0x3B, M162_PORTB = 0x38, M162_PORTC = 0x35,
	M162_PORTD = 0x32, M162_PORTE = 0x27,
	M162_UDR0 = 0x2C, M162_UDR1 = 0x23,
	/* vector numbers (avr-libc's, RESET = 0; the datasheet counts from 1) */
	M162_TIMER0_COMP_VECT = 16, M162_TIMER0_OVF_VECT = 17,
};

/* A new, initialised and reset ATmega162 at 1 MHz.  Its sleep callback does nothing:
 * SLEEP still jumps simulated time to the next event, but pacing against the wall
 * clock is the caller's business.  NULL when out of memory. */
avr_t *atmega162_new(void);

/* USART n (0 or 1): simavr's UART and its current timing in CPU cycles. */
avr_uart_t *atmega162_uart(avr_t *avr, int n);
avr_cycle_count_t atmega162_uart_bit_cycles(avr_t *avr, int n);
avr_cycle_count_t atmega162_uart_frame_cycles(avr_t *avr, int n);

/* Call fn after the CPU reads (or writes) the register at data address addr, after the
 * peripheral that owns it has done its part.  Returns 0, or -1 when the hook table is full. */
typedef void (*atmega162_hook_t)(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param);
int atmega162_after_read(avr_t *avr, avr_io_addr_t addr, atmega162_hook_t fn, void *param);
int atmega162_after_write(avr_t *avr, avr_io_addr_t addr, atmega162_hook_t fn, void *param);

/* Port data address of PORT<letter> ('A'..'E'), 0 for anything else. */
avr_io_addr_t atmega162_port_addr(char letter);

#endif

/* Where the harness plugs a HexBot module's outside world into the two ATmega162s, from
 * firmware/include/hexbot_gen.h (generated from bus/pins.py, the project's one truth).
 * Ports are indices 0..4 = A..E. */
#ifndef HEXBOT_PINS_H
#define HEXBOT_PINS_H

#include <stdint.h>

#include "../include/hexbot_gen.h"

/* Control board: the DIP switches are all eight pins of this port; --dip N closes the
 * switches of N's one bits, and a closed switch reads PINS_DIP_ACTIVE_LOW ? 0 : 1. */
#define PINS_DIP_PORT DIP_PORT
#define PINS_DIP_ACTIVE_LOW DIP_ACTIVE_LOW

/* Comm board: the optical switch of side k (1..6) is bit PINS_SWITCH_MASKS[k] of port
 * PINS_SWITCH_PORTS[k]; a neighbour there (--switches bit k-1) closes it, and a closed
 * switch reads PINS_SWITCH_ACTIVE_LOW ? 0 : 1 (an open one the other level: the pull-up). */
static const uint8_t PINS_SWITCH_PORTS[7] = OPTICAL_SWITCH_PORTS;
static const uint8_t PINS_SWITCH_MASKS[7] = OPTICAL_SWITCH_MASKS;
#define PINS_SWITCH_ACTIVE_LOW OPTICAL_SWITCH_ACTIVE_LOW

/* Comm board: the IR multiplexer in front of USART1, selected by PORTA bits; the centre
 * transceiver (the one a PC above the module sees) is on channel IR_CENTRE_CHANNEL. */
#define PINS_IR_MUX_PORT IR_SEL_PORT
#define PINS_IR_MUX_A IR_SEL_A_BIT
#define PINS_IR_MUX_B IR_SEL_B_BIT
#define PINS_IR_MUX_C IR_SEL_C_BIT
#define PINS_IR_CENTRE IR_CENTRE_CHANNEL

#endif

/* The host library's interface to the simulator (module_sim/firmware.py mirrors it with
 * ctypes): per step, the received bytes go in, port writes and transmissions come out in
 * the order the program made them, with the time it wants to be stepped again. A step that
 * makes more than the buffers hold hands them over on the way (hexbot_flush): none is lost. */
#ifndef HEXBOT_HOST_H
#define HEXBOT_HOST_H

#include <stddef.h>
#include <stdint.h>

#define HEXBOT_MAX_EVENTS 256
#define HEXBOT_MAX_BYTES 1024

enum { HEXBOT_EV_PORT = 1, HEXBOT_EV_TX = 2 };

typedef struct {
    uint8_t kind;    /* HEXBOT_EV_PORT: port a became n; HEXBOT_EV_TX: n bytes on UART a */
    uint8_t a;
    uint8_t n;
    uint8_t pad;
    uint16_t offset; /* HEXBOT_EV_TX: first byte in bytes[] / starts[] */
    uint16_t pad2;
} hexbot_event_t;

typedef struct {
    uint64_t wake;   /* sim time (ns) to step again, 0: only when a byte arrives */
    uint8_t rx[2][4];
    uint8_t rx_n[2];    /* bytes waiting in each receiver, set before a step */
    uint8_t rx_used[2]; /* how many the step read */
    uint16_t n_events;
    uint16_t n_bytes;
    uint16_t overflow;  /* events of the step lost: the buffers were full, no hexbot_flush */
    uint16_t pad;
    hexbot_event_t events[HEXBOT_MAX_EVENTS];
    uint8_t bytes[HEXBOT_MAX_BYTES];
    uint64_t starts[HEXBOT_MAX_BYTES]; /* start bit of each byte (ns) */
} hexbot_io_t;

extern hexbot_io_t hexbot_io;

/* Called in a step whose events or bytes fill the buffers: the simulator takes what they hold
 * (as after the step), then the step goes on with them empty. NULL: what does not fit is
 * counted in hexbot_io.overflow, not kept. */
typedef void (*hexbot_flush_fn)(void);
extern hexbot_flush_fn hexbot_flush;

size_t hexbot_state_size(void);
void hexbot_state_init(void *state);
void hexbot_setup(void *state, uint64_t boot, uint32_t byte_ns0, uint32_t byte_ns1);
void hexbot_set_pins(void *state, const uint8_t pins[5]);
void hexbot_step(void *state, uint64_t now);

#endif

/* The board layer on the host: the firmware as a virtual module's program (module_sim/
 * firmware.py). Time, the UART line and the received bytes come from the simulator; port
 * writes and transmissions go back to it, in order, as events of the step.
 *
 * Everything a board holds (the program's statics and this file's) is one block of memory,
 * `hexbot_state` (the Makefile moves the objects' .data and .bss there): the simulator keeps
 * one copy per module and hexbot_step() swaps it in and out, so one loaded library runs any
 * number of boards. The UART's transmit timing is module_sim.avr.Uart.write, in C. */
#include <string.h>

#include "hexbot.h"
#include "hexbot_host.h"

/* --- per board (in hexbot_state) --------------------------------------------------- */
static uint64_t now, boot;
static uint32_t byte_ns[2];
static uint64_t udr_free_at[2], line_free_at[2];
static uint8_t tx_pending[2];
static uint64_t tx_done_at[2];
static uint8_t port[5], pin[5];

/* --- per step (shared, outside hexbot_state) --------------------------------------- */
extern hexbot_io_t hexbot_io;

static void wake_at(uint64_t t)
{
    if (t > now && (hexbot_io.wake == 0 || t < hexbot_io.wake))
        hexbot_io.wake = t;
}

static uint64_t tick_count(void)
{
    return (now - boot) / TICK_NS;
}

uint16_t board_ticks(void)
{
    return (uint16_t)tick_count();
}

uint8_t board_tick_reached(uint16_t target)
{
    uint64_t ticks = tick_count();
    int16_t left = (int16_t)(target - (uint16_t)ticks);
    if (left <= 0)
        return 1;
    wake_at(boot + (ticks + (uint64_t)left) * TICK_NS);
    return 0;
}

uint8_t board_rx_ready(uint8_t uart)
{
    return hexbot_io.rx_used[uart] < hexbot_io.rx_n[uart];
}

uint8_t board_rx_read(uint8_t uart)
{
    return board_rx_ready(uart) ? hexbot_io.rx[uart][hexbot_io.rx_used[uart]++] : 0;
}

/* The next event of the step (n: the port's value, or the burst's length), with room for
 * `bytes` bytes after it. When the buffers are full the simulator takes what they hold first
 * (hexbot_flush); with nobody to take them the event is counted as lost (hexbot_io.overflow)
 * and NULL returned: never dropped unseen. */
static hexbot_event_t *new_event(uint8_t kind, uint8_t a, uint8_t n, uint8_t bytes)
{
    if (hexbot_io.n_events >= HEXBOT_MAX_EVENTS || hexbot_io.n_bytes + bytes > HEXBOT_MAX_BYTES) {
        if (!hexbot_flush) {
            if (hexbot_io.overflow < UINT16_MAX)
                hexbot_io.overflow++;
            return NULL;
        }
        hexbot_flush();
        hexbot_io.n_events = 0;
        hexbot_io.n_bytes = 0;
    }
    hexbot_event_t *e = &hexbot_io.events[hexbot_io.n_events++];
    e->kind = kind;
    e->a = a;
    e->n = n;
    e->offset = hexbot_io.n_bytes;
    return e;
}

/* Uart.write: each byte waits for UDR, then for the line; returns when the last byte is in
 * UDR. The burst is one event, as the model's program hands it over in one Tx. */
static uint64_t line_write(uint8_t uart, const uint8_t *data, uint8_t flash, uint8_t n)
{
    uint64_t w = now;
    if (!n)
        return w;
    hexbot_event_t *e = new_event(HEXBOT_EV_TX, uart, n, n);
    for (uint8_t k = 0; k < n; k++) {
        uint64_t start;
        if (udr_free_at[uart] > w)
            w = udr_free_at[uart];
        start = w > line_free_at[uart] ? w : line_free_at[uart];
        udr_free_at[uart] = start;
        line_free_at[uart] = start + byte_ns[uart];
        if (e) {
            hexbot_io.bytes[hexbot_io.n_bytes] = flash ? fw_byte(&data[k]) : data[k];
            hexbot_io.starts[hexbot_io.n_bytes++] = start;
        }
    }
    return w;
}

uint8_t board_tx_ready(uint8_t uart)
{
    if (udr_free_at[uart] <= now)
        return 1;
    wake_at(udr_free_at[uart]);
    return 0;
}

void board_tx_write(uint8_t uart, uint8_t byte)
{
    line_write(uart, &byte, 0, 1);
}

uint8_t board_tx_some(uint8_t uart, const uint8_t *data, uint8_t flash, uint8_t k, uint8_t len)
{
    if (!tx_pending[uart]) { /* the whole burst now, each byte timed as UDR and the line allow */
        tx_done_at[uart] = line_write(uart, data + k, flash, (uint8_t)(len - k));
        tx_pending[uart] = 1;
    }
    if (tx_done_at[uart] <= now) {
        tx_pending[uart] = 0;
        return len;
    }
    wake_at(tx_done_at[uart]);
    return k;
}

uint8_t board_tx_queue(uint8_t uart, const uint8_t *data, uint8_t n)
{
    line_write(uart, data, 0, n);
    return 1;
}

uint8_t board_port(uint8_t p)
{
    return port[p];
}

void board_port_write(uint8_t p, uint8_t value)
{
    if (port[p] == value)
        return;
    port[p] = value;
    new_event(HEXBOT_EV_PORT, p, value, 0);
}

uint8_t board_pins(uint8_t p)
{
    return pin[p];
}

void board_init(const uint8_t outputs[5], const uint8_t pullups[5])
{
    (void)outputs;
    (void)pullups; /* hexbot_setup sets them: the power-up state, before any step */
}

/* --- the simulator's entry points ------------------------------------------------ */
extern char __start_hexbot_state[], __stop_hexbot_state[];

size_t hexbot_state_size(void)
{
    return (size_t)(__stop_hexbot_state - __start_hexbot_state);
}

void hexbot_state_init(void *state)
{
    memcpy(state, __start_hexbot_state, hexbot_state_size());
}

/* Power-up: the board's clock started at boot_ns, its UARTs' byte times. */
void hexbot_setup(void *state, uint64_t boot_ns, uint32_t byte_ns0, uint32_t byte_ns1)
{
    memcpy(__start_hexbot_state, state, hexbot_state_size());
    boot = boot_ns;
    byte_ns[0] = byte_ns0;
    byte_ns[1] = byte_ns1;
    memcpy(port, program_pullups, sizeof port); /* board_init's pull-ups, as at power-up */
    memcpy(state, __start_hexbot_state, hexbot_state_size());
}

/* The levels on the input pins (DIP switches, optical switches), until changed. */
void hexbot_set_pins(void *state, const uint8_t pins[5])
{
    memcpy(__start_hexbot_state, state, hexbot_state_size());
    memcpy(pin, pins, sizeof pin);
    memcpy(state, __start_hexbot_state, hexbot_state_size());
}

/* One step at sim time t with hexbot_io.rx_n bytes waiting; the events and the wake-up are
 * in hexbot_io after it. */
void hexbot_step(void *state, uint64_t t)
{
    memcpy(__start_hexbot_state, state, hexbot_state_size());
    now = t;
    hexbot_io.wake = 0;
    hexbot_io.n_events = 0;
    hexbot_io.n_bytes = 0;
    hexbot_io.overflow = 0;
    hexbot_io.rx_used[0] = hexbot_io.rx_used[1] = 0;
    program_step();
    memcpy(state, __start_hexbot_state, hexbot_state_size());
    hexbot_io.rx_n[0] = hexbot_io.rx_n[1] = 0; /* the simulator sets them when bytes wait */
}

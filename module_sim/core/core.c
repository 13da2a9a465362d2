/* The fleet core: every virtual module's two boards, the UART0 line between them, the IR
 * multiplexer and the world's IR medium, in one event loop over arrays (issue: fleet core).
 *
 * Python enters once per window (core_run): the loop runs every event before `until` in time
 * order and stops early, at the end of an instant, when something outside must act (a coil
 * changed that the mechanics must judge now: core_set_coil_rule; a byte reached a receiver
 * outside the core where its framer may act: the PC's, a twin's). What the window produced waits in the output buffers (core_out_*),
 * every byte on every wire with its start time, for module_sim.core to frame and publish.
 *
 * The boards run the robot's own program: the host build of firmware/ (firmware/host), one
 * shared library per board kind, dlopen'ed here and stepped with each board's state block as
 * module_sim.firmware does from Python. Geometry stays in Python: it gives each module's
 * routes (which receiver the light of each transceiver reaches) and the multiplexer's table.
 *
 * The medium is module_sim/air.py's model, kept exactly (docs/physics.md): the line at a
 * receiver is low while any carrier holds it low (a start bit or a 0 data bit), and the
 * receiver's USART reads each data bit of a byte as the majority of three samples mid-bit on
 * that line. The receiver keeps the line's low spans merged, so a byte's value is 24 lookups
 * at its stop bit, whatever the number of carriers in flight: a pile-up costs O(bytes log), not
 * O(carriers x bytes). A byte is garbled when another transmitter's byte overlaps it. A
 * receiver delivers a byte at its stop bit; of two garbled bytes overlapping on one line only
 * the first to complete forms a byte (bus/ir.py, IrReceiver).
 */
#define _GNU_SOURCE /* memfd_create */
#include <dlfcn.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "hexbot_host.h"

#define NO_TIME UINT64_MAX
#define EXT_SRC (1 << 28) /* sources outside the core: EXT_SRC + j (the core's modules: 0..) */
#define RX_DEPTH 3 /* two in the FIFO and one in the receive shift register (module_sim/avr.py) */

enum { EV_WAKE = 1, EV_RX0, EV_IRDONE };
/* OUT_PORTS: a module's ten port bytes (control A..E, comm A..E) after an instant's writes */
enum { OUT_TX = 1, OUT_PORTS, OUT_RX, OUT_OVERRUN, OUT_COLLISION };
/* why core_put_light refused a burst (0: it did not) */
enum { LIGHT_LENGTHS = 1, LIGHT_SOURCE, LIGHT_RECEIVER, LIGHT_BYTE_TIME, LIGHT_START };
/* wires of a module in OUT_TX: 0 UART0 up (ctrl->comm), 1 down, 2 debug, 3+k IR transceiver k */
enum { W_UP = 0, W_DOWN = 1, W_DEBUG = 2, W_IR = 3 };

typedef struct {
    uint64_t t, seq;
    uint32_t kind, a, b, pad;
} ev_t;

/* Frames rendered here (core_set_wire, core_add_parts, core_render_frames): a frame waits in
 * a queue until the window passes its last byte, then becomes its envelope's bytes,
 * bus.transport.frame_json's parts around its times, seq and wall time. */
typedef struct {
    uint64_t t_last, ordinal, first;
    uint32_t m, wire, parts;
} fq_t;

typedef struct {
    char *s;            /* p0 p1 p2 back to back */
    uint32_t n0, n1, n2;
    uint32_t link, rawn;
    uint8_t *raw;       /* whole-write key (NULL: not in the map) */
    uint32_t once;      /* one frame's (PARTS_ONCE): freed when it is rendered */
} parts_t;

/* core_add_parts' `use` */
enum { PARTS_KEPT = 0, PARTS_WHOLE = 1, PARTS_ONCE = 2 };

typedef struct {
    char *key, *names0, *names1;
    uint32_t keyn, n0, n1, link;
} wire_t;

typedef struct {
    uint8_t *d;
    size_t n, cap;
} buf_t;

#define N_WIRES 10 /* W_IR + 7 transceivers */

typedef struct {
    void *lib;
    size_t size;
    void (*step)(void *, uint64_t);
    void (*setup)(void *, uint64_t, uint32_t, uint32_t);
    void (*set_pins)(void *, const uint8_t *);
    hexbot_io_t *io;
    hexbot_flush_fn *flush;
    uint8_t *power_on;
    const uint8_t *pullups; /* the program's program_pullups: its ports at power-up */
    int fd; /* the anonymous file of the core's own copy of the library (open_private) */
} prog_t;

typedef struct {
    uint64_t wake_at;
    uint32_t wake_gen;
    uint32_t byte_ns[2];
    uint8_t rx[2][RX_DEPTH];
    uint8_t rx_n[2];
    uint8_t port[5];
    uint8_t on;
    uint8_t gone; /* its module left the core (core_remove_modules): it never steps again */
} board_t;

typedef struct { /* a byte in the air at a receiver */
    uint64_t start, end;
    int32_t src;
    uint8_t sent, corrupt_in, done; /* done: its stop bit has been */
    uint8_t pad;
    int32_t next_free;
} member_t;

typedef struct {
    uint64_t a, b;
} span_t;

typedef struct { /* a span a transmitter's light covers at a receiver (touching bytes merged) */
    uint64_t a, b;
    int32_t src, pad;
} run_t;

typedef struct {
    int32_t *air; /* bytes in the air (members), sorted by (start, end) */
    uint32_t n, cap;
    span_t *low; /* where the line is held low: disjoint spans, sorted */
    uint32_t n_low, cap_low;
    run_t *runs; /* the transmitters' light, for a collision's sources */
    uint32_t n_runs, cap_runs;
    int32_t module;     /* the core's module whose transceiver this is, -1: outside the core */
    int32_t k;          /* its transceiver */
    uint64_t longest;
    uint64_t line_busy; /* the end of the last byte delivered (IrReceiver._line_busy) */
    uint8_t has_busy;
    uint8_t gone; /* left the core with its module or its fleet: light reaching it is lost */
    /* A framed receiver outside the core (core_frame_receiver): while its framer can only wait
     * for more bytes, a byte it gets stops nothing (see quiet_byte). */
    uint8_t framed;
    uint32_t q_pos;      /* bytes the framer holds (0: empty) */
    uint32_t q_n;        /* templates still possible */
    int16_t *q_alive, *q_next;
} receiver_t;

typedef struct {
    uint64_t t, aux;
    uint32_t kind, m;
    int32_t a, b, n;
    uint32_t off, off2, n2;
} out_t;

/* ports_dirty's bits */
#define DIRTY_PORTS 1
#define DIRTY_COILS 2
/* What a coil change of a module means to the window (core_set_coil_rule): */
#define COIL_STOP 0   /* the mechanics acts on it now: the window ends with its instant */
#define COIL_MAGNETS 1 /* the world is at rest: only a change that leaves a magnet pair (two
                        * neighbouring sides negative) or both relays of a side on can start
                        * something; any other is judged as well at the window's end */
#define COIL_FREE 2   /* nobody acts on it (no mechanics) */

typedef struct {
    prog_t prog[2]; /* 0 control, 1 comm */
    uint32_t n_modules, n_receivers, cap_modules, cap_receivers, n_ext_srcs, cap_ext_srcs;
    board_t *boards;
    uint8_t *state[2];
    int8_t mux_table[256];
    int32_t *mux;            /* selected transceiver, -1: Y7 (unwired) */
    uint64_t *mux_at;        /* when the multiplexer last moved */
    int32_t *route;          /* 7 per module: receiver the light of transceiver k reaches, -1 none */
    int32_t *module_rx;      /* 7 per module: the receiver of transceiver k */
    uint8_t ir_sel_port;
    uint8_t coil_mask[5]; /* the control board's solenoid and magnet bits, per port */
    uint8_t *ports_dirty;  /* per module: DIRTY_PORTS, DIRTY_COILS in this instant */
    uint8_t *coil_rule;    /* per module: COIL_* (core_set_coil_rule) */
    uint8_t magnet_pins[6][4]; /* per side: port and mask of its + relay, of its - relay */
    uint32_t *dirty;       /* those modules, in the order they changed */
    uint32_t n_dirty;
    /* events */
    ev_t *heap;
    uint32_t heap_n, heap_cap;
    uint64_t seq;
    uint64_t now;
    /* medium */
    receiver_t *rcv;
    member_t *mem_pool;
    uint32_t mem_cap, mem_used;
    int32_t mem_free;
    uint32_t *src_mark;     /* per module (source m) */
    uint32_t *ext_mark;     /* per source outside the core (EXT_SRC + j) */
    uint32_t mark;
    /* outputs of the window */
    out_t *out;
    uint32_t out_n, out_cap;
    uint8_t *out_bytes;
    uint64_t *out_starts;
    uint32_t bytes_n, bytes_cap;
    int32_t *out_srcs;
    uint32_t srcs_n, srcs_cap;
    uint8_t *scratch; /* medium_add's values of a burst (any length) */
    uint32_t scratch_n, scratch_cap;
    span_t *burst_runs; /* medium_add's burst, touching bytes merged */
    uint32_t burst_runs_n, burst_runs_cap;
    int stop;
    /* frames */
    wire_t *wires;          /* N_WIRES per module (core_set_wire) */
    uint8_t *wire_empty;    /* N_WIRES per module: Python's framer of the wire holds nothing */
    uint32_t *fleet_of;     /* per module: its fleet's output buffer */
    uint32_t *seq_of;       /* 2 per module: the next frame seq of its control, comm board */
    parts_t *parts;
    uint32_t parts_n, parts_cap;
    uint32_t *parts_free;   /* ids of rendered PARTS_ONCE entries, for reuse */
    uint32_t parts_free_n, parts_free_cap;
    uint32_t *pmap;         /* open addressing: parts id + 1 of (link, whole write); 0 empty */
    uint32_t pmap_cap, pmap_n;
    fq_t *fq;
    uint32_t fq_n, fq_cap;
    uint64_t ordinal;       /* writes on wires so far (frames of one instant keep their order) */
    buf_t *fleet_out;
    uint32_t n_fleets;
    int stepping; /* the board whose step runs (hexbot_flush) */
    /* the framer grammar of framed receivers (core_set_grammar): patterns, -1 a free byte */
    int16_t *tpl_pat;    /* n_tpl x tpl_max */
    uint8_t *tpl_len;
    uint32_t n_tpl, tpl_max;
    int16_t *first;      /* per first byte: the templates that do not fail on it */
    uint32_t first_at[257];
    char error[256];
} core_t;

/* The core whose board is stepping on this thread: the library's flush hook (no argument)
 * needs it. Each core has its own copy of the libraries (load), so cores on two threads do
 * not meet. */
static _Thread_local core_t *g_core;

#define GROW(ptr, n, cap, need)                                                                  \
    do {                                                                                         \
        if ((n) + (need) > (cap)) {                                                              \
            uint32_t c_ = (cap) ? (cap) : 64;                                                    \
            while (c_ < (n) + (need))                                                            \
                c_ *= 2;                                                                         \
            void *p_ = realloc((ptr), (size_t)c_ * sizeof *(ptr));                               \
            if (!p_) {                                                                           \
                fprintf(stderr, "hexbench core: out of memory\n");                               \
                abort();                                                                         \
            }                                                                                    \
            (ptr) = p_;                                                                          \
            (cap) = c_;                                                                          \
        }                                                                                        \
    } while (0)

/* A binary min-heap of `type` in c->field (count c->field##_n, capacity c->field##_cap) ordered
 * by less(): NAME_push and NAME_pop. */
#define DEFINE_HEAP(name, type, field, less)                                                     \
    static void name##_push(core_t *c, type e)                                                   \
    {                                                                                            \
        GROW(c->field, c->field##_n, c->field##_cap, 1);                                         \
        uint32_t i = c->field##_n++;                                                             \
        while (i) {                                                                              \
            uint32_t p = (i - 1) / 2;                                                            \
            if (!less(&e, &c->field[p]))                                                         \
                break;                                                                           \
            c->field[i] = c->field[p];                                                           \
            i = p;                                                                               \
        }                                                                                        \
        c->field[i] = e;                                                                         \
    }                                                                                            \
    static type name##_pop(core_t *c)                                                            \
    {                                                                                            \
        type top = c->field[0], last = c->field[--c->field##_n];                                 \
        uint32_t i = 0, n = c->field##_n;                                                        \
        for (;;) {                                                                               \
            uint32_t l = 2 * i + 1, r = l + 1, m = i;                                            \
            const type *best = &last;                                                            \
            if (l < n && less(&c->field[l], best)) {                                             \
                m = l;                                                                           \
                best = &c->field[l];                                                             \
            }                                                                                    \
            if (r < n && less(&c->field[r], best))                                               \
                m = r;                                                                           \
            if (m == i)                                                                          \
                break;                                                                           \
            c->field[i] = c->field[m];                                                           \
            i = m;                                                                               \
        }                                                                                        \
        if (n)                                                                                   \
            c->field[i] = last;                                                                  \
        return top;                                                                              \
    }

/* --- the event heap: (t, seq), seq in scheduling order as the Python clock's ties ---------- */
static int ev_less(const ev_t *x, const ev_t *y)
{
    return x->t < y->t || (x->t == y->t && x->seq < y->seq);
}

DEFINE_HEAP(ev, ev_t, heap, ev_less)

static void push(core_t *c, uint64_t t, uint32_t kind, uint32_t a, uint32_t b)
{
    ev_t e = {t < c->now ? c->now : t, c->seq++, kind, a, b, 0};
    ev_push(c, e);
}

static ev_t pop(core_t *c)
{
    return ev_pop(c);
}

/* --- outputs -------------------------------------------------------------------------------- */
static out_t *out_new(core_t *c, uint32_t kind, uint64_t t, uint32_t m)
{
    GROW(c->out, c->out_n, c->out_cap, 1);
    out_t *o = &c->out[c->out_n++];
    memset(o, 0, sizeof *o);
    o->kind = kind;
    o->t = t;
    o->m = m;
    return o;
}

static uint32_t out_put_bytes(core_t *c, const uint8_t *data, const uint64_t *starts, uint32_t n)
{
    if (c->bytes_n + n > c->bytes_cap) {
        uint32_t cap = c->bytes_cap ? c->bytes_cap : 4096;
        while (cap < c->bytes_n + n)
            cap *= 2;
        c->out_bytes = realloc(c->out_bytes, cap);
        c->out_starts = realloc(c->out_starts, (size_t)cap * sizeof *c->out_starts);
        if (!c->out_bytes || !c->out_starts)
            abort();
        c->bytes_cap = cap;
    }
    uint32_t off = c->bytes_n;
    memcpy(c->out_bytes + off, data, n);
    if (starts)
        memcpy(c->out_starts + off, starts, (size_t)n * sizeof *starts);
    else
        memset(c->out_starts + off, 0, (size_t)n * sizeof *starts);
    c->bytes_n += n;
    return off;
}

/* --- the medium ------------------------------------------------------------------------------- */
static int32_t mem_alloc(core_t *c)
{
    int32_t m;
    if (c->mem_free >= 0) {
        m = c->mem_free;
        c->mem_free = c->mem_pool[m].next_free;
    } else {
        GROW(c->mem_pool, c->mem_used, c->mem_cap, 1);
        m = (int32_t)c->mem_used++;
    }
    return m;
}

static uint32_t *mark_of(core_t *c, int32_t src)
{
    return src >= EXT_SRC ? &c->ext_mark[src - EXT_SRC] : &c->src_mark[src];
}

/* first byte in r's air with (start, end) >= (t, end) */
static uint32_t air_lower(const core_t *c, const receiver_t *r, uint64_t t, uint64_t end)
{
    uint32_t lo = 0, hi = r->n;
    while (lo < hi) {
        uint32_t mid = (lo + hi) / 2;
        const member_t *s = &c->mem_pool[r->air[mid]];
        if (s->start < t || (s->start == t && s->end < end))
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* Is r's line low at t (some carrier in a start bit or a 0 data bit)? */
static int line_low(const receiver_t *r, uint64_t t)
{
    uint32_t lo = 0, hi = r->n_low; /* the first span starting after t */
    while (lo < hi) {
        uint32_t mid = (lo + hi) / 2;
        if (r->low[mid].a <= t)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo > 0 && r->low[lo - 1].b > t;
}

/* A carrier holds r's line low from a to b: merge the span in (air.py Air._hold_low). */
static void hold_low(receiver_t *r, uint64_t a, uint64_t b)
{
    uint32_t lo = 0, hi = r->n_low; /* i: the first span ending at or after a */
    while (lo < hi) {
        uint32_t mid = (lo + hi) / 2;
        if (r->low[mid].b < a)
            lo = mid + 1;
        else
            hi = mid;
    }
    uint32_t i = lo, j = i; /* j: past the spans starting at or before b */
    while (j < r->n_low && r->low[j].a <= b)
        j++;
    if (i < j) {
        if (r->low[i].a < a)
            a = r->low[i].a;
        if (r->low[j - 1].b > b)
            b = r->low[j - 1].b;
        r->low[i].a = a;
        r->low[i].b = b;
        memmove(r->low + i + 1, r->low + j, (size_t)(r->n_low - j) * sizeof *r->low);
        r->n_low -= j - i - 1;
        return;
    }
    GROW(r->low, r->n_low, r->cap_low, 1);
    memmove(r->low + i + 1, r->low + i, (size_t)(r->n_low - i) * sizeof *r->low);
    r->low[i].a = a;
    r->low[i].b = b;
    r->n_low++;
}

/* A byte's carrier: its start bit and each run of 0 data bits hold the line low (bit time j
 * spans start + j*byte_ns/10 .. start + (j+1)*byte_ns/10; air.py low_spans). */
static void hold_byte(receiver_t *r, uint64_t start, uint64_t byte_ns, uint8_t sent)
{
    uint32_t j = 0;
    while (j < 9) {
        if (j == 0 || !(sent >> (j - 1) & 1)) {
            uint32_t k = j + 1;
            while (k < 9 && !(sent >> (k - 1) & 1))
                k++;
            hold_low(r, start + j * byte_ns / 10, start + k * byte_ns / 10);
            j = k;
        } else {
            j++;
        }
    }
}

/* What the USART reads of a byte sent as `sent` from `start`: each data bit the majority of
 * its samples 8, 9 and 10 of 16 on the line (air.py sample_times). */
static uint8_t uart_value(const receiver_t *r, uint64_t start, uint64_t byte_ns, uint8_t sent)
{
    uint8_t v = sent;
    for (uint32_t k = 0; k < 8; k++) {
        if (!(sent >> k & 1))
            continue;
        int lows = 0;
        for (uint64_t s = 7; s <= 9; s++)
            lows += line_low(r, start + (16 * (k + 1) + s) * byte_ns / 160);
        if (lows >= 2)
            v &= (uint8_t)~(1u << k);
    }
    return v;
}

/* Does another transmitter's byte overlap start..end at r? */
static int overlapped(const core_t *c, const receiver_t *r, int32_t src, uint64_t start, uint64_t end)
{
    uint64_t from = start + 1 > r->longest ? start + 1 - r->longest : 0;
    for (uint32_t j = air_lower(c, r, from, 0); j < r->n; j++) {
        const member_t *mb = &c->mem_pool[r->air[j]];
        if (mb->start >= end)
            break;
        if (mb->end > start && mb->src != src)
            return 1;
    }
    return 0;
}

/* Forget what no byte still to come or still to complete can meet: a byte completing now
 * began at now - longest at the earliest. */
static void medium_forget(core_t *c, receiver_t *r)
{
    uint64_t horizon = c->now > r->longest ? c->now - r->longest : 0;
    uint32_t k = 0;
    while (k < r->n_low && r->low[k].b <= horizon)
        k++;
    if (k) {
        memmove(r->low, r->low + k, (size_t)(r->n_low - k) * sizeof *r->low);
        r->n_low -= k;
    }
    k = 0;
    while (k < r->n) {
        member_t *mb = &c->mem_pool[r->air[k]];
        if (!mb->done || mb->start + r->longest > horizon)
            break;
        mb->next_free = c->mem_free;
        c->mem_free = r->air[k];
        k++;
    }
    if (k) {
        memmove(r->air, r->air + k, (size_t)(r->n - k) * sizeof *r->air);
        r->n -= k;
    }
}

/* A burst reaches receiver `ri` (air.py Air.collide, then Air.add): its bytes' values on the
 * line as it is now (for the collision event), the sources it meets, then its carrier on the
 * line and its bytes in the air, each delivered at its stop bit. */
static void medium_add(core_t *c, int32_t ri, int32_t src, const uint8_t *data, const uint64_t *starts,
                       uint32_t n, uint32_t byte_ns, const uint8_t *corrupt_in)
{
    receiver_t *r = &c->rcv[ri];
    medium_forget(c, r);
    if (byte_ns > r->longest)
        r->longest = byte_ns;
    /* a burst is carried whole: light from outside the core may be longer than a board's */
    c->scratch_n = 0;
    GROW(c->scratch, c->scratch_n, c->scratch_cap, n);
    uint8_t *values = c->scratch;
    int any_hit = 0;
    c->burst_runs_n = 0;
    for (uint32_t i = 0; i < n; i++) {
        uint64_t start = starts[i], end = start + byte_ns;
        values[i] = uart_value(r, start, byte_ns, data[i]);
        any_hit |= overlapped(c, r, src, start, end);
        span_t *last = c->burst_runs_n ? &c->burst_runs[c->burst_runs_n - 1] : NULL;
        if (last && start <= last->b) {
            if (end > last->b)
                last->b = end;
        } else {
            GROW(c->burst_runs, c->burst_runs_n, c->burst_runs_cap, 1);
            c->burst_runs[c->burst_runs_n].a = start;
            c->burst_runs[c->burst_runs_n++].b = end;
        }
    }
    /* the transmitters whose light meets this burst's (each run checked once, not per byte) */
    uint64_t horizon = c->now > r->longest ? c->now - r->longest : 0;
    uint32_t first_src_off = c->srcs_n;
    c->mark++;
    for (uint32_t j = 0; j < r->n_runs;) {
        run_t *ru = &r->runs[j];
        if (ru->b <= horizon) { /* over: forget it */
            *ru = r->runs[--r->n_runs];
            continue;
        }
        j++;
        if (!any_hit || ru->src == src || *mark_of(c, ru->src) == c->mark)
            continue;
        uint32_t lo = 0, hi = c->burst_runs_n; /* the first of the burst's runs ending after a */
        while (lo < hi) {
            uint32_t mid = (lo + hi) / 2;
            if (c->burst_runs[mid].b <= ru->a)
                lo = mid + 1;
            else
                hi = mid;
        }
        if (lo < c->burst_runs_n && c->burst_runs[lo].a < ru->b) {
            *mark_of(c, ru->src) = c->mark;
            GROW(c->out_srcs, c->srcs_n, c->srcs_cap, 1);
            c->out_srcs[c->srcs_n++] = ru->src;
        }
    }
    if (any_hit) {
        GROW(c->out_srcs, c->srcs_n, c->srcs_cap, 1);
        c->out_srcs[c->srcs_n++] = src;
        out_t *o = out_new(c, OUT_COLLISION, c->now, (uint32_t)ri);
        o->a = src;
        o->off = first_src_off;
        o->n = (int32_t)(c->srcs_n - first_src_off);
        o->off2 = out_put_bytes(c, values, NULL, n);
        o->n2 = n;
    }
    GROW(r->runs, r->n_runs, r->cap_runs, c->burst_runs_n);
    for (uint32_t j = 0; j < c->burst_runs_n; j++) {
        run_t *ru = &r->runs[r->n_runs++];
        ru->a = c->burst_runs[j].a;
        ru->b = c->burst_runs[j].b;
        ru->src = src;
        ru->pad = 0;
    }
    GROW(r->air, r->n, r->cap, n);
    for (uint32_t i = 0; i < n; i++) {
        uint64_t start = starts[i], end = start + byte_ns;
        hold_byte(r, start, byte_ns, data[i]);
        int32_t mi = mem_alloc(c);
        member_t *mb = &c->mem_pool[mi];
        mb->start = start;
        mb->end = end;
        mb->src = src;
        mb->sent = data[i];
        mb->corrupt_in = (uint8_t)(corrupt_in && corrupt_in[i]);
        mb->done = 0;
        uint32_t j = air_lower(c, r, start, end);
        memmove(r->air + j + 1, r->air + j, (size_t)(r->n - j) * sizeof *r->air);
        r->air[j] = mi;
        r->n++;
        push(c, end, EV_IRDONE, (uint32_t)ri, (uint32_t)mi);
    }
}

static void uart_receive(core_t *c, uint32_t b, int u, uint8_t byte);

/* Does a byte leave the framed receiver r's framer waiting for more (bus.framer.Framer._scan:
 * some template still possible needs more bytes)? Then nobody outside acts on it now, and
 * the window need not stop: it reaches them, at its own time, at the window's end. A byte
 * that ends a frame, or noise, or fails every template stops the window (and r waits for
 * Python to tell its framer's state again). */
static int quiet_byte(core_t *c, receiver_t *r, uint8_t v)
{
    uint32_t p = r->q_pos, n = 0, nc;
    const int16_t *cand;
    if (p == 0) {
        cand = c->first + c->first_at[v];
        nc = c->first_at[v + 1] - c->first_at[v];
    } else {
        cand = r->q_alive;
        nc = r->q_n;
    }
    for (uint32_t i = 0; i < nc; i++) {
        int16_t t = cand[i];
        int16_t e = c->tpl_pat[(size_t)t * c->tpl_max + p];
        if ((e < 0 || e == v) && c->tpl_len[t] > p + 1)
            r->q_next[n++] = t;
    }
    if (n == 0) {
        r->framed = 0;
        return 0;
    }
    int16_t *x = r->q_alive;
    r->q_alive = r->q_next;
    r->q_next = x;
    r->q_n = n;
    r->q_pos = p + 1;
    return 1;
}

/* A byte's stop bit at receiver ri (IrReceiver._complete, then VirtualModule._ir_rx). */
static void ir_done(core_t *c, uint32_t ri, int32_t mi)
{
    member_t *mb = &c->mem_pool[mi];
    receiver_t *r = &c->rcv[ri];
    mb->done = 1; /* it stays in the air while a later byte may still overlap it */
    if (r->gone)
        return;
    /* every carrier that meets it is on the line by now: it began before this stop bit */
    uint8_t value = uart_value(r, mb->start, mb->end - mb->start, mb->sent);
    int bad = mb->corrupt_in || overlapped(c, r, mb->src, mb->start, mb->end);
    uint64_t start = mb->start;
    int32_t src = mb->src;
    /* two garbled bytes overlapping on one line are one byte: the first to complete carries it */
    if (bad && r->has_busy && start < r->line_busy)
        return;
    r->line_busy = c->now;
    r->has_busy = 1;
    if (r->module >= 0) {
        uint32_t m = (uint32_t)r->module;
        int32_t k = r->k;
        if (c->mux[m] == k && c->mux_at[m] <= start) {
            uart_receive(c, 2 * m + 1, 1, value);
        }
        return;
    }
    out_t *o = out_new(c, OUT_RX, c->now, ri);
    o->a = value;
    o->b = bad;
    o->aux = start;
    o->n = src;
    if (!(r->framed && quiet_byte(c, r, value)))
        c->stop = 1;
}

/* --- frames ---------------------------------------------------------------------------------- */
static int fq_less(const fq_t *a, const fq_t *b)
{
    return a->t_last < b->t_last || (a->t_last == b->t_last && a->ordinal < b->ordinal);
}

DEFINE_HEAP(fq, fq_t, fq, fq_less)

static uint64_t parts_hash(uint32_t link, const uint8_t *raw, uint32_t n)
{
    uint64_t h = 1469598103934665603ull ^ link;
    for (uint32_t i = 0; i < n; i++)
        h = (h ^ raw[i]) * 1099511628211ull;
    return h;
}

/* The parts of a whole write of `n` bytes on a wire of `link` that Python's framer, empty,
 * turns into exactly one frame of those bytes (core_add_parts with whole), or -1. */
static int32_t parts_find(const core_t *c, uint32_t link, const uint8_t *raw, uint32_t n)
{
    if (!c->pmap_cap)
        return -1;
    uint32_t mask = c->pmap_cap - 1;
    for (uint32_t i = (uint32_t)parts_hash(link, raw, n) & mask;; i = (i + 1) & mask) {
        uint32_t id = c->pmap[i];
        if (!id)
            return -1;
        const parts_t *p = &c->parts[id - 1];
        if (p->link == link && p->rawn == n && !memcmp(p->raw, raw, n))
            return (int32_t)(id - 1);
    }
}

static void pmap_put(core_t *c, uint32_t id)
{
    if (2 * (c->pmap_n + 1) > c->pmap_cap) {
        uint32_t old = c->pmap_cap, *was = c->pmap;
        c->pmap_cap = old ? 2 * old : 1024;
        c->pmap = calloc(c->pmap_cap, sizeof *c->pmap);
        if (!c->pmap)
            abort();
        c->pmap_n = 0;
        for (uint32_t i = 0; i < old; i++)
            if (was[i])
                pmap_put(c, was[i] - 1);
        free(was);
    }
    const parts_t *p = &c->parts[id];
    uint32_t mask = c->pmap_cap - 1;
    uint32_t i = (uint32_t)parts_hash(p->link, p->raw, p->rawn) & mask;
    while (c->pmap[i])
        i = (i + 1) & mask;
    c->pmap[i] = id + 1;
    c->pmap_n++;
}

static void buf_put(buf_t *b, const void *data, size_t n)
{
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 65536;
        while (cap < b->n + n)
            cap *= 2;
        b->d = realloc(b->d, cap);
        if (!b->d)
            abort();
        b->cap = cap;
    }
    memcpy(b->d + b->n, data, n);
    b->n += n;
}

static void buf_u64(buf_t *b, uint64_t v)
{
    char tmp[24];
    int i = 24;
    do {
        tmp[--i] = (char)('0' + v % 10);
        v /= 10;
    } while (v);
    buf_put(b, tmp + i, (size_t)(24 - i));
}

static void wire_clear(wire_t *w)
{
    free(w->key);
    free(w->names0);
    free(w->names1);
    w->key = w->names0 = w->names1 = NULL;
}

/* A PARTS_ONCE entry has served its frame: its slot is reused. */
static void parts_done(core_t *c, uint32_t id)
{
    parts_t *p = &c->parts[id];
    if (!p->once)
        return;
    free(p->s);
    p->s = NULL;
    p->once = 0;
    GROW(c->parts_free, c->parts_free_n, c->parts_free_cap, 1);
    c->parts_free[c->parts_free_n++] = id;
}

/* One frame's sample in pack_batch's layout: u16 key length, u32 payload length (LE), the key,
 * the envelope (bus.transport.frame_json: p0 names0 p1 t_last wall seq p2 first names1). */
static void render_frame(core_t *c, const fq_t *f, uint64_t wall)
{
    const wire_t *w = &c->wires[(size_t)N_WIRES * f->m + f->wire];
    const parts_t *p = &c->parts[f->parts];
    buf_t *b = &c->fleet_out[c->fleet_of[f->m]];
    uint32_t board = (f->wire == W_UP || f->wire == W_DEBUG) ? 0 : 1;
    uint8_t head[6] = {(uint8_t)w->keyn, (uint8_t)(w->keyn >> 8)};
    size_t at = b->n;
    buf_put(b, head, 6);
    buf_put(b, w->key, w->keyn);
    size_t start = b->n;
    buf_put(b, p->s, p->n0);
    buf_put(b, w->names0, w->n0);
    buf_put(b, p->s + p->n0, p->n1);
    buf_u64(b, f->t_last);
    buf_put(b, ",\"wall_time_ns\":", 16);
    buf_u64(b, wall);
    buf_put(b, ",\"seq\":", 7);
    buf_u64(b, c->seq_of[2 * f->m + board]++);
    buf_put(b, p->s + p->n0 + p->n1, p->n2);
    buf_u64(b, f->first);
    buf_put(b, w->names1, w->n1);
    uint32_t len = (uint32_t)(b->n - start);
    memcpy(b->d + at + 2, &len, 4); /* little-endian hosts (x86, arm) */
    parts_done(c, f->parts);
}

/* --- boards --------------------------------------------------------------------------------- */
static void step_board(core_t *c, uint32_t b);

static void replay(core_t *c, uint32_t b)
{
    prog_t *p = &c->prog[b & 1];
    hexbot_io_t *io = p->io;
    uint32_t m = b / 2;
    board_t *bd = &c->boards[b];
    for (uint32_t i = 0; i < io->n_events; i++) {
        const hexbot_event_t *e = &io->events[i];
        if (e->kind == HEXBOT_EV_PORT) {
            uint8_t old = bd->port[e->a];
            bd->port[e->a] = e->n;
            if ((b & 1) && e->a == c->ir_sel_port) {
                int32_t k = c->mux_table[e->n];
                if (k != c->mux[m]) {
                    c->mux[m] = k;
                    c->mux_at[m] = c->now;
                }
            }
            if (!c->ports_dirty[m])
                c->dirty[c->n_dirty++] = m;
            c->ports_dirty[m] |= DIRTY_PORTS;
            if (!(b & 1) && ((old ^ e->n) & c->coil_mask[e->a]))
                c->ports_dirty[m] |= DIRTY_COILS; /* judged at the instant's end (core_flush_ports) */
            continue;
        }
        const uint8_t *data = io->bytes + e->offset;
        const uint64_t *starts = io->starts + e->offset;
        uint32_t n = e->n, byte_ns = bd->byte_ns[e->a];
        int wire;
        if (e->a == 0) { /* UART0: the other board hears each byte at its stop bit */
            uint32_t other = b ^ 1;
            for (uint32_t k = 0; k < n; k++)
                push(c, starts[k] + byte_ns, EV_RX0, other, data[k]);
            wire = (b & 1) ? W_DOWN : W_UP;
        } else if (!(b & 1)) {
            wire = W_DEBUG;
        } else {
            int32_t k = c->mux[m];
            if (k < 0)
                continue; /* channel Y7 is not wired: the light goes nowhere */
            wire = W_IR + k;
            int32_t ri = c->route[7 * m + k];
            if (ri >= 0)
                medium_add(c, ri, (int32_t)m, data, starts, n, byte_ns, NULL);
        }
        uint64_t ordinal = c->ordinal++;
        size_t wi = (size_t)N_WIRES * m + (uint32_t)wire;
        if (c->wire_empty[wi]) {
            /* a whole frame Python's framer knows: rendered here when its last byte ends */
            int32_t parts = parts_find(c, c->wires[wi].link, data, n);
            if (parts >= 0) {
                fq_t f = {starts[n - 1] + byte_ns, ordinal, starts[0], m, (uint32_t)wire, (uint32_t)parts};
                fq_push(c, f);
                continue;
            }
        }
        c->wire_empty[wi] = 0; /* Python frames it, and says when its framer is empty again */
        out_t *o = out_new(c, OUT_TX, c->now, m);
        o->a = wire;
        o->n = (int32_t)n;
        o->off = out_put_bytes(c, data, starts, n);
        o->b = (int32_t)byte_ns;
        o->aux = ordinal;
    }
    io->n_events = 0;
    io->n_bytes = 0;
}

static void flushed(void)
{
    if (g_core && g_core->stepping >= 0)
        replay(g_core, (uint32_t)g_core->stepping);
}

static void step_board(core_t *c, uint32_t b)
{
    board_t *bd = &c->boards[b];
    prog_t *p = &c->prog[b & 1];
    hexbot_io_t *io = p->io;
    for (int u = 0; u < 2; u++) {
        uint8_t n = bd->rx_n[u] < 4 ? bd->rx_n[u] : 4;
        io->rx_n[u] = n;
        memcpy(io->rx[u], bd->rx[u], n);
    }
    core_t *saved_core = g_core;
    int saved_stepping = c->stepping;
    hexbot_flush_fn saved = *p->flush;
    g_core = c;
    c->stepping = (int)b;
    *p->flush = flushed;
    p->step(c->state[b & 1] + (size_t)(b / 2) * p->size, c->now);
    *p->flush = saved;
    c->stepping = saved_stepping;
    g_core = saved_core;
    if (io->overflow)
        snprintf(c->error, sizeof c->error, "board %u: the firmware's step lost %u events", b, io->overflow);
    for (int u = 0; u < 2; u++) {
        uint8_t used = io->rx_used[u];
        if (used) {
            memmove(bd->rx[u], bd->rx[u] + used, (size_t)(bd->rx_n[u] - used));
            bd->rx_n[u] = (uint8_t)(bd->rx_n[u] - used);
        }
    }
    uint64_t wake = io->wake;
    replay(c, b);
    if (wake != bd->wake_at) { /* a new wake-up time (an unchanged one stays booked) */
        bd->wake_gen++;
        if (wake)
            push(c, wake, EV_WAKE, b, bd->wake_gen);
        bd->wake_at = wake;
    }
}

static void uart_receive(core_t *c, uint32_t b, int u, uint8_t byte)
{
    board_t *bd = &c->boards[b];
    if (bd->gone)
        return;
    if (bd->rx_n[u] >= RX_DEPTH) { /* DOR: the byte waiting in the shift register is lost */
        out_t *o = out_new(c, OUT_OVERRUN, c->now, b);
        o->a = u;
        o->b = bd->rx[u][RX_DEPTH - 1];
        o->n = (b & 1) && u == 1 ? c->mux[b / 2] : -2;
        bd->rx[u][RX_DEPTH - 1] = byte;
        return;
    }
    bd->rx[u][bd->rx_n[u]++] = byte;
    if (bd->on) /* before power-up a byte waits in the FIFO, as module_sim/avr.py's Uart */
        step_board(c, b);
}

static void dispatch(core_t *c, const ev_t *e)
{
    switch (e->kind) {
    case EV_WAKE: {
        board_t *bd = &c->boards[e->a];
        if (e->b != bd->wake_gen || bd->gone)
            return; /* cancelled: the program asked for another time since, or it left */
        bd->wake_at = 0;
        step_board(c, e->a);
        return;
    }
    case EV_RX0:
        uart_receive(c, e->a, 0, (uint8_t)e->b);
        return;
    case EV_IRDONE:
        ir_done(c, e->a, (int32_t)e->b);
        return;
    }
}

/* --- the API (module_sim/core/__init__.py) -------------------------------------------------- */
/* A private copy of the host library at `path`: dlopen gives every caller of one file the
 * same copy, whose globals (hexbot_io, hexbot_flush, the state area a step swaps in) would be
 * shared by every core of the process and Python's drivers. A copy in an anonymous file is
 * a library of its own. Its file stays open while it is loaded: dlopen knows a library by
 * the name it was opened by first (/proc/self/fd/N), and N must not be reused meanwhile. */
static void *open_private(core_t *c, prog_t *p, const char *path)
{
    FILE *in = fopen(path, "rb");
    int fd = p->fd = memfd_create("hexbot-host", MFD_CLOEXEC);
    void *lib = NULL;
    if (in && fd >= 0) {
        char buf[65536], name[64];
        size_t n;
        int ok = 1;
        while (ok && (n = fread(buf, 1, sizeof buf, in)) > 0)
            ok = write(fd, buf, n) == (ssize_t)n;
        snprintf(name, sizeof name, "/proc/self/fd/%d", fd);
        if (ok && !ferror(in))
            lib = dlopen(name, RTLD_NOW | RTLD_LOCAL);
    }
    if (in)
        fclose(in);
    if (!lib)
        snprintf(c->error, sizeof c->error, "cannot load a private copy of %s: %s", path,
                 in && fd >= 0 ? dlerror() : "no file or no memfd_create");
    return lib;
}

static int load(core_t *c, int k, const char *path, const uint8_t *power_on)
{
    prog_t *p = &c->prog[k];
    p->lib = open_private(c, p, path);
    if (!p->lib)
        return -1;
    size_t (*size)(void) = (size_t(*)(void))dlsym(p->lib, "hexbot_state_size");
    p->step = (void (*)(void *, uint64_t))dlsym(p->lib, "hexbot_step");
    p->setup = (void (*)(void *, uint64_t, uint32_t, uint32_t))dlsym(p->lib, "hexbot_setup");
    p->set_pins = (void (*)(void *, const uint8_t *))dlsym(p->lib, "hexbot_set_pins");
    p->io = (hexbot_io_t *)dlsym(p->lib, "hexbot_io");
    p->flush = (hexbot_flush_fn *)dlsym(p->lib, "hexbot_flush");
    p->pullups = (const uint8_t *)dlsym(p->lib, "program_pullups");
    if (!size || !p->step || !p->setup || !p->set_pins || !p->io || !p->flush || !p->pullups) {
        snprintf(c->error, sizeof c->error, "%s is not a hexbot host library (make -C firmware host)", path);
        return -1;
    }
    p->size = size();
    /* the state at power-up comes from the one copy taken before any board ran (Python's
     * module_sim.firmware.Program): the library's own block holds the last board stepped */
    p->power_on = malloc(p->size ? p->size : 1);
    memcpy(p->power_on, power_on, p->size);
    return 0;
}

const char *core_error(core_t *c)
{
    return c->error;
}

core_t *core_new(const char *control_lib, const char *comm_lib, const uint8_t *control_power_on,
                 const uint8_t *comm_power_on, const int8_t *mux_table, uint32_t ir_sel_port,
                 const uint8_t coil_mask[5])
{
    core_t *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->stepping = -1;
    c->mem_free = -1;
    c->prog[0].fd = c->prog[1].fd = -1;
    if (load(c, 0, control_lib, control_power_on) || load(c, 1, comm_lib, comm_power_on))
        return c; /* core_error says why */
    memcpy(c->mux_table, mux_table, 256);
    memcpy(c->coil_mask, coil_mask, 5);
    c->ir_sel_port = (uint8_t)ir_sel_port;
    return c;
}

#define RESIZE(ptr, n)                                                                           \
    do {                                                                                         \
        void *p_ = realloc((ptr), (size_t)(n) * sizeof *(ptr));                                  \
        if (!p_)                                                                                 \
            abort();                                                                             \
        (ptr) = p_;                                                                              \
    } while (0)

/* A receiver: transceiver k of module m, or (m = -1) one outside the core. */
static int32_t add_receiver(core_t *c, int32_t m, int32_t k)
{
    if (c->n_receivers == c->cap_receivers) {
        c->cap_receivers = c->cap_receivers ? 2 * c->cap_receivers : 64;
        RESIZE(c->rcv, c->cap_receivers);
    }
    receiver_t *r = &c->rcv[c->n_receivers];
    memset(r, 0, sizeof *r);
    r->module = m;
    r->k = k;
    return (int32_t)c->n_receivers++;
}

/* n more modules (a fleet's): returns the first one's index; their receivers are
 * core_receiver(m, k). Each starts at power-off, its light going nowhere. */
uint32_t core_add_modules(core_t *c, uint32_t n)
{
    uint32_t first = c->n_modules, total = first + n;
    if (total > c->cap_modules) {
        uint32_t cap = c->cap_modules ? c->cap_modules : 16;
        while (cap < total)
            cap *= 2;
        RESIZE(c->boards, 2 * (size_t)cap);
        for (int k = 0; k < 2; k++)
            RESIZE(c->state[k], c->prog[k].size * (size_t)cap + 1);
        RESIZE(c->mux, cap);
        RESIZE(c->mux_at, cap);
        RESIZE(c->route, 7 * (size_t)cap);
        RESIZE(c->src_mark, cap);
        RESIZE(c->module_rx, 7 * (size_t)cap);
        RESIZE(c->ports_dirty, cap);
        RESIZE(c->coil_rule, cap);
        RESIZE(c->wires, (size_t)N_WIRES * cap);
        RESIZE(c->wire_empty, (size_t)N_WIRES * cap);
        RESIZE(c->fleet_of, cap);
        RESIZE(c->seq_of, 2 * (size_t)cap);
        RESIZE(c->dirty, cap);
        c->cap_modules = cap;
    }
    for (uint32_t m = first; m < total; m++) {
        memset(&c->boards[2 * m], 0, 2 * sizeof *c->boards);
        for (int k = 0; k < 2; k++)
            memcpy(c->state[k] + c->prog[k].size * m, c->prog[k].power_on, c->prog[k].size);
        c->mux[m] = c->mux_table[0];
        c->mux_at[m] = 0;
        c->src_mark[m] = 0;
        c->ports_dirty[m] = 0;
        c->coil_rule[m] = COIL_STOP;
        memset(&c->wires[(size_t)N_WIRES * m], 0, N_WIRES * sizeof *c->wires);
        memset(&c->wire_empty[(size_t)N_WIRES * m], 0, N_WIRES); /* Python frames until core_set_wire */
        c->fleet_of[m] = 0;
        c->seq_of[2 * m] = c->seq_of[2 * m + 1] = 0;
        for (int k = 0; k < 7; k++) {
            c->route[7 * m + k] = -1;
            c->module_rx[7 * m + k] = add_receiver(c, (int32_t)m, k);
        }
    }
    c->n_modules = total;
    return first;
}

int32_t core_receiver(core_t *c, uint32_t m, uint32_t k)
{
    return c->module_rx[7 * m + k];
}

/* A receiver outside the core (the PC's, a twin's transceiver). */
int32_t core_add_external_receiver(core_t *c)
{
    return add_receiver(c, -1, 0);
}

/* The framer grammar of framed receivers: n templates, pats[n][max] (-1 a free byte), their
 * lengths, and for each first byte b the templates first[first_at[b]..first_at[b+1]). */
int core_set_grammar(core_t *c, uint32_t n, uint32_t max, const int16_t *pats, const uint8_t *lens,
                     const int16_t *first, const uint32_t *first_at)
{
    free(c->tpl_pat);
    free(c->tpl_len);
    free(c->first);
    c->tpl_pat = malloc((size_t)n * max * sizeof *c->tpl_pat);
    c->tpl_len = malloc(n);
    c->first = malloc((size_t)first_at[256] * sizeof *c->first + 1);
    if (!c->tpl_pat || !c->tpl_len || !c->first)
        return -1;
    memcpy(c->tpl_pat, pats, (size_t)n * max * sizeof *pats);
    memcpy(c->tpl_len, lens, n);
    memcpy(c->first, first, (size_t)first_at[256] * sizeof *first);
    memcpy(c->first_at, first_at, sizeof c->first_at);
    c->n_tpl = n;
    c->tpl_max = max;
    return 0;
}

/* Receiver ri's framer holds pos bytes and waits on the n templates alive (pos 0: empty): its
 * bytes stop a window only where the framer may act (quiet_byte). */
int core_frame_receiver(core_t *c, int32_t ri, uint32_t pos, uint32_t n, const int16_t *alive)
{
    receiver_t *r = &c->rcv[ri];
    if (!r->q_alive) {
        r->q_alive = malloc((c->n_tpl + 1) * sizeof *r->q_alive);
        r->q_next = malloc((c->n_tpl + 1) * sizeof *r->q_next);
        if (!r->q_alive || !r->q_next)
            return -1;
    }
    if (n > c->n_tpl || (pos && !n))
        return -1;
    memcpy(r->q_alive, alive, n * sizeof *alive);
    r->q_n = n;
    r->q_pos = pos;
    r->framed = 1;
    return 0;
}

/* A source of light outside the core: its id for core_put_light. */
int32_t core_add_external_source(core_t *c)
{
    if (c->n_ext_srcs == c->cap_ext_srcs) {
        c->cap_ext_srcs = c->cap_ext_srcs ? 2 * c->cap_ext_srcs : 16;
        RESIZE(c->ext_mark, c->cap_ext_srcs);
    }
    c->ext_mark[c->n_ext_srcs] = 0;
    return EXT_SRC + (int32_t)c->n_ext_srcs++;
}

void core_free(core_t *c)
{
    if (!c)
        return;
    for (uint32_t i = 0; i < c->n_receivers; i++) {
        free(c->rcv[i].air);
        free(c->rcv[i].low);
        free(c->rcv[i].runs);
        free(c->rcv[i].q_alive);
        free(c->rcv[i].q_next);
    }
    free(c->tpl_pat);
    free(c->tpl_len);
    free(c->first);
    free(c->burst_runs);
    free(c->mem_pool);
    free(c->rcv);
    free(c->src_mark);
    free(c->ext_mark);
    free(c->module_rx);
    free(c->ports_dirty);
    free(c->coil_rule);
    for (size_t i = 0; i < (size_t)N_WIRES * c->n_modules; i++)
        wire_clear(&c->wires[i]);
    free(c->wires);
    free(c->wire_empty);
    free(c->fleet_of);
    free(c->seq_of);
    for (uint32_t i = 0; i < c->parts_n; i++) {
        free(c->parts[i].s);
        free(c->parts[i].raw);
    }
    free(c->parts);
    free(c->parts_free);
    free(c->pmap);
    free(c->fq);
    for (uint32_t i = 0; i < c->n_fleets; i++)
        free(c->fleet_out[i].d);
    free(c->fleet_out);
    free(c->dirty);
    free(c->heap);
    free(c->out);
    free(c->out_bytes);
    free(c->out_starts);
    free(c->out_srcs);
    free(c->scratch);
    free(c->boards);
    free(c->state[0]);
    free(c->state[1]);
    free(c->mux);
    free(c->mux_at);
    free(c->route);
    for (int k = 0; k < 2; k++) {
        free(c->prog[k].power_on);
        if (c->prog[k].lib)
            dlclose(c->prog[k].lib); /* the core's own copy */
        if (c->prog[k].fd >= 0)
            close(c->prog[k].fd);
    }
    free(c);
}

void core_set_route(core_t *c, uint32_t m, uint32_t k, int32_t receiver)
{
    c->route[7 * m + k] = receiver;
}

void core_set_pins(core_t *c, uint32_t b, const uint8_t pins[5])
{
    prog_t *p = &c->prog[b & 1];
    p->set_pins(c->state[b & 1] + (size_t)(b / 2) * p->size, pins);
}

/* Power-up of board b at `t` (now): FirmwareDriver.power_up. */
void core_power_up(core_t *c, uint32_t b, uint64_t t, uint32_t byte_ns0, uint32_t byte_ns1,
                   const uint8_t pins[5])
{
    board_t *bd = &c->boards[b];
    prog_t *p = &c->prog[b & 1];
    uint8_t *state = c->state[b & 1] + (size_t)(b / 2) * p->size;
    c->now = t;
    bd->on = 1;
    bd->byte_ns[0] = byte_ns0;
    bd->byte_ns[1] = byte_ns1;
    /* hexbot_setup sets the board's ports to its pull-ups without an event: the records start
     * from them, as the Mcu's ports do (control_board/comm_board: board_init's pull-ups) */
    memcpy(bd->port, p->pullups, sizeof bd->port);
    p->setup(state, t, byte_ns0, byte_ns1);
    p->set_pins(state, pins);
    step_board(c, b);
}

/* Light from outside the core (the PC, a twin, a Python-program module) reaching `n_rcv`
 * receivers, written now (`t`): n bytes, n_starts start times, n_corrupt flags (0: none).
 * A sample from elsewhere may be anything: lengths that disagree, a receiver or source the
 * core does not have, a zero byte time or a start whose byte would end past the clock's
 * range change nothing and return which (module_sim.core says it in a bad-sample event). */
int32_t core_put_light(core_t *c, uint64_t t, int32_t src, uint32_t n_rcv, const int32_t *rcv,
                       const uint8_t *data, uint32_t n, const uint64_t *starts, uint32_t n_starts,
                       uint32_t byte_ns, const uint8_t *corrupt, uint32_t n_corrupt)
{
    if (n_starts != n || (corrupt && n_corrupt != n))
        return LIGHT_LENGTHS;
    if (src < EXT_SRC || src - EXT_SRC >= (int32_t)c->n_ext_srcs)
        return LIGHT_SOURCE;
    for (uint32_t i = 0; i < n_rcv; i++)
        if (rcv[i] < 0 || (uint32_t)rcv[i] >= c->n_receivers)
            return LIGHT_RECEIVER;
    if (!byte_ns)
        return LIGHT_BYTE_TIME;
    for (uint32_t i = 0; i < n; i++)
        if (starts[i] > NO_TIME - 1 - byte_ns)
            return LIGHT_START;
    c->now = t;
    for (uint32_t i = 0; i < n_rcv; i++)
        medium_add(c, rcv[i], src, data, starts, n, byte_ns, corrupt);
    return 0;
}

/* Modules first..first+n-1 leave the core (their fleet is removed): their boards stop as at
 * power-off and never step again, their light goes nowhere, light still in the air to their
 * receivers is lost. Their indexes are not reused. */
int32_t core_remove_modules(core_t *c, uint32_t first, uint32_t n)
{
    if (first > c->n_modules || n > c->n_modules - first)
        return -1;
    for (uint32_t m = first; m < first + n; m++) {
        for (uint32_t b = 2 * m; b < 2 * m + 2; b++) {
            board_t *bd = &c->boards[b];
            bd->on = 0;
            bd->gone = 1;
            bd->wake_gen++; /* its booked wake-up is void */
            bd->wake_at = 0;
            bd->rx_n[0] = bd->rx_n[1] = 0;
        }
        for (int k = 0; k < 7; k++) {
            c->route[7 * m + k] = -1;
            c->rcv[c->module_rx[7 * m + k]].gone = 1;
        }
    }
    return 0;
}

/* A receiver outside the core leaves it (its fleet is removed). */
int32_t core_remove_receiver(core_t *c, int32_t ri)
{
    if (ri < 0 || (uint32_t)ri >= c->n_receivers)
        return -1;
    c->rcv[ri].gone = 1;
    return 0;
}

/* Per side S1..S6 of the control board: port index and mask of its + relay, then of its -
 * relay (bus.pins MAGNET_POS, MAGNET_NEG). */
void core_set_magnet_pins(core_t *c, const uint8_t pins[24])
{
    memcpy(c->magnet_pins, pins, 24);
}

/* What a coil change of modules first..first+n-1 means to the window (COIL_*). */
void core_set_coil_rule(core_t *c, uint32_t first, uint32_t n, uint32_t rule)
{
    if (first + n <= c->n_modules)
        memset(c->coil_rule + first, (int)rule, n);
}

uint64_t core_next(core_t *c)
{
    uint64_t t = c->heap_n ? c->heap[0].t : NO_TIME;
    if (c->fq_n && c->fq[0].t_last < t)
        t = c->fq[0].t_last; /* a frame the window must pass to publish */
    return t;
}

static char *dup_n(const char *s, uint32_t n)
{
    char *d = malloc(n ? n : 1);
    if (!d)
        abort();
    memcpy(d, s, n);
    return d;
}

/* Wire `wire` of module m: its fleet's output buffer, its link (parts_find's key), its frames'
 * key and the envelope's names (bus.transport.frame_json). Python frames nothing of it since
 * (its framer is empty). */
void core_set_wire(core_t *c, uint32_t m, uint32_t wire, uint32_t fleet, uint32_t link, const char *key,
                   uint32_t keyn, const char *names0, uint32_t n0, const char *names1, uint32_t n1)
{
    if (m >= c->n_modules || wire >= N_WIRES)
        return;
    if (fleet >= c->n_fleets) {
        c->fleet_out = realloc(c->fleet_out, (size_t)(fleet + 1) * sizeof *c->fleet_out);
        if (!c->fleet_out)
            abort();
        memset(c->fleet_out + c->n_fleets, 0, (size_t)(fleet + 1 - c->n_fleets) * sizeof *c->fleet_out);
        c->n_fleets = fleet + 1;
    }
    wire_t *w = &c->wires[(size_t)N_WIRES * m + wire];
    wire_clear(w);
    w->key = dup_n(key, keyn);
    w->names0 = dup_n(names0, n0);
    w->names1 = dup_n(names1, n1);
    w->keyn = keyn;
    w->n0 = n0;
    w->n1 = n1;
    w->link = link;
    c->fleet_of[m] = fleet;
    c->wire_empty[(size_t)N_WIRES * m + wire] = 1;
}

/* Python's framer of the wire holds nothing again (1) or does (0). */
void core_wire_empty(core_t *c, uint32_t m, uint32_t wire, uint32_t empty)
{
    if (m < c->n_modules && wire < N_WIRES && c->wires[(size_t)N_WIRES * m + wire].key)
        c->wire_empty[(size_t)N_WIRES * m + wire] = (uint8_t)(empty != 0);
}

/* A frame's parts (p0, p1, p2 of bus.transport.frame_json_parts). `use`: PARTS_KEPT, kept for
 * the frames Python queues with them; PARTS_WHOLE, kept, and a write of exactly `raw` on an
 * empty wire of `link` is this frame (the core renders it without Python); PARTS_ONCE, for one
 * frame (noise, or more distinct frames than Python keeps), freed once it is rendered. */
uint32_t core_add_parts(core_t *c, uint32_t link, const uint8_t *raw, uint32_t rawn, uint32_t use,
                        const char *p0, uint32_t n0, const char *p1, uint32_t n1, const char *p2, uint32_t n2)
{
    uint32_t id;
    if (use == PARTS_ONCE && c->parts_free_n) {
        id = c->parts_free[--c->parts_free_n];
    } else {
        GROW(c->parts, c->parts_n, c->parts_cap, 1);
        id = c->parts_n++;
    }
    parts_t *p = &c->parts[id];
    p->s = malloc((size_t)n0 + n1 + n2 + 1);
    if (!p->s)
        abort();
    memcpy(p->s, p0, n0);
    memcpy(p->s + n0, p1, n1);
    memcpy(p->s + n0 + n1, p2, n2);
    p->n0 = n0;
    p->n1 = n1;
    p->n2 = n2;
    p->link = link;
    p->rawn = rawn;
    p->raw = NULL;
    p->once = use == PARTS_ONCE;
    if (use == PARTS_WHOLE) {
        p->raw = (uint8_t *)dup_n((const char *)raw, rawn);
        pmap_put(c, id);
    }
    return id;
}

/* A frame Python framed (a write it was handed, OUT_TX's `aux` its ordinal). */
void core_queue_frame(core_t *c, uint32_t m, uint32_t wire, uint64_t t_last, uint64_t ordinal, uint64_t first,
                      uint32_t parts)
{
    if (m >= c->n_modules || wire >= N_WIRES || parts >= c->parts_n || !c->wires[(size_t)N_WIRES * m + wire].key)
        return;
    fq_t f = {t_last, ordinal, first, m, wire, parts};
    fq_push(c, f);
}

/* Every queued frame whose last byte ended by `now`, in that order, into its fleet's buffer. */
uint32_t core_render_frames(core_t *c, uint64_t now)
{
    uint32_t n = 0;
    uint64_t wall = 0;
    while (c->fq_n && c->fq[0].t_last <= now) {
        fq_t f = fq_pop(c);
        if (c->boards[2 * f.m].gone) {
            parts_done(c, f.parts);
            continue;
        }
        if (!n) {
            struct timespec ts;
            clock_gettime(CLOCK_REALTIME, &ts);
            wall = (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
        }
        render_frame(c, &f, wall);
        n++;
    }
    return n;
}

/* Fleet f's rendered samples (pack_batch's bytes) and their length; cleared by Python. */
const uint8_t *core_fleet_out(core_t *c, uint32_t f, uint64_t *n)
{
    if (f >= c->n_fleets) {
        *n = 0;
        return NULL;
    }
    *n = c->fleet_out[f].n;
    return c->fleet_out[f].d;
}

void core_fleet_out_clear(core_t *c, uint32_t f)
{
    if (f < c->n_fleets)
        c->fleet_out[f].n = 0;
}

/* Frames of modules first..first+n-1 still queued are dropped (their fleet left). */
void core_drop_frames(core_t *c, uint32_t first, uint32_t n)
{
    uint32_t k = 0;
    for (uint32_t i = 0; i < c->fq_n; i++) {
        if (c->fq[i].m < first || c->fq[i].m >= first + n)
            c->fq[k++] = c->fq[i];
        else
            parts_done(c, c->fq[i].parts);
    }
    uint32_t total = k;
    c->fq_n = 0;
    for (uint32_t i = 0; i < total; i++) /* re-heap (in place: push reads only below i) */
        fq_push(c, c->fq[i]);
}

/* Can the control board's ports `p` start a move or a fault (COIL_MAGNETS)? A magnet pair
 * (two neighbouring sides negative, the sides' ring being the same in the body's frame) or a
 * side with both relays on. */
static int magnets_may_act(const core_t *c, const uint8_t *p)
{
    int neg[6];
    for (int s = 0; s < 6; s++) {
        const uint8_t *pin = c->magnet_pins[s];
        int pos = (p[pin[0]] & pin[1]) != 0;
        neg[s] = (p[pin[2]] & pin[3]) != 0;
        if (pos && neg[s])
            return 1;
        neg[s] = neg[s] && !pos;
    }
    for (int s = 0; s < 6; s++)
        if (neg[s] && neg[(s + 1) % 6])
            return 1;
    return 0;
}

/* The ports of every module written in the instant that ends: one record each. A coil
 * change ends the window with this instant unless the module's rule lets it wait. */
void core_flush_ports(core_t *c)
{
    for (uint32_t i = 0; i < c->n_dirty; i++) {
        uint32_t m = c->dirty[i];
        uint8_t dirty = c->ports_dirty[m];
        c->ports_dirty[m] = 0;
        if (c->boards[2 * m].gone)
            continue;
        if (dirty & DIRTY_COILS) {
            uint8_t rule = c->coil_rule[m];
            if (rule == COIL_STOP || (rule == COIL_MAGNETS && magnets_may_act(c, c->boards[2 * m].port)))
                c->stop = 1;
        }
        uint8_t ports[10];
        memcpy(ports, c->boards[2 * m].port, 5);
        memcpy(ports + 5, c->boards[2 * m + 1].port, 5);
        out_t *o = out_new(c, OUT_PORTS, c->now, m);
        o->off = out_put_bytes(c, ports, NULL, 10);
        o->n = 10;
    }
    c->n_dirty = 0;
}

/* Run every event before `until`; stop at the end of the first instant that made an output
 * someone outside must act on. Returns the time reached (the last instant run). */
uint64_t core_run(core_t *c, uint64_t until)
{
    c->stop = 0;
    while (c->heap_n && c->heap[0].t < until) {
        uint64_t t = c->heap[0].t;
        if (t > c->now && c->n_dirty)
            core_flush_ports(c);
        if (c->stop && t > c->now)
            break;
        c->now = t;
        ev_t e = pop(c);
        dispatch(c, &e);
        if (c->error[0])
            break;
    }
    core_flush_ports(c);
    return c->now;
}

/* The window's outputs: records, their bytes and start times, the collision sources. */
uint32_t core_out_n(core_t *c) { return c->out_n; }
uint32_t core_out_nbytes(core_t *c) { return c->bytes_n; }
uint32_t core_out_nsrcs(core_t *c) { return c->srcs_n; }
out_t *core_out(core_t *c) { return c->out; }
uint8_t *core_out_bytes(core_t *c) { return c->out_bytes; }
uint64_t *core_out_starts(core_t *c) { return c->out_starts; }
int32_t *core_out_srcs(core_t *c) { return c->out_srcs; }

void core_out_clear(core_t *c)
{
    c->out_n = 0;
    c->bytes_n = 0;
    c->srcs_n = 0;
}

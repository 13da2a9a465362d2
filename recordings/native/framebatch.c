/* The recorder's batch path for frames (recordings/native.py, Recorder.write_batch).
 *
 * fb_frames() turns frame envelopes, as the bus writes them, into MCAP message records: per
 * frame, its own message and the foxglove.Log line derived from it, exactly the records
 * Recorder.write makes of each frame (the same bytes, sequence numbers and chunk offsets).
 * It stops and returns a code whenever Python must act in between: a sample that is not such
 * an envelope (Python writes it as Recorder.write would), a channel not registered yet, a Log
 * line not seen yet, a chunk that is full, an output buffer that is full. fb_index() writes a
 * chunk's MessageIndex records. No Python API: loaded with ctypes.
 *
 * Records (an actuator record above all: most of a fleet's samples) are written here too when
 * Python has written the same bytes but their sim_time_ns digits on the same channel before
 * (fb_record_seen: checked, counted and derived there) and their coils (joints and magnets)
 * are those of the channel's last record Python saw: then Python's careful path would write
 * the same message, count it by topic and derive nothing (the scene draws joints and magnets
 * only). Anything else is Python's, in its place.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

enum {
    FB_DONE = 0, FB_NOT_FRAME = 1, FB_NEW_CHANNEL = 2, FB_NEW_LOG_CHANNEL = 3, FB_REST_MISS = 4,
    FB_CHUNK_FULL = 5, FB_OUT_FULL = 6, FB_GROW_SEQS = 7,
};

#define MESSAGE_HEADER 31 /* opcode, record length, channel, sequence, log time, publish time */
#define MAX_DIGITS 19     /* a longer time is left to Python (which has big integers) */
#define MAX_TIME (1ULL << 62)
#define MAX_RESTS 65536   /* then the table starts over, as FrameLog's cache does */

/* ---- the Log lines already seen: (head, kind) -> the encoded Log without its timestamp ---- */
typedef struct {
    uint64_t hash;
    uint8_t *key; /* head, then kind */
    int32_t head_len, kind_len, tag; /* tag: the channel of a record's (head, tail); 0 for Log lines */
    uint8_t *rest;
    int32_t rest_len;
} slot_t;

typedef struct {
    slot_t *slots;
    int64_t cap, count;
} table_t;

static uint64_t mix(const uint8_t *p, int64_t n, uint64_t h) { /* eight bytes at a time */
    for (; n >= 8; p += 8, n -= 8) {
        uint64_t w;
        memcpy(&w, p, 8);
        h = (h ^ w) * 0x9E3779B97F4A7C15ULL;
        h ^= h >> 29;
    }
    uint64_t w = 0;
    memcpy(&w, p, (size_t)n);
    h = (h ^ w ^ ((uint64_t)n << 56)) * 0x9E3779B97F4A7C15ULL;
    return h ^ (h >> 32);
}

static uint64_t key_hash(const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl) {
    return mix(kind, kl, mix(head, hl, 0x243F6A8885A308D3ULL));
}

table_t *fb_table_new(void) {
    table_t *t = calloc(1, sizeof *t);
    if (!t) return NULL;
    t->cap = 1024;
    t->slots = calloc((size_t)t->cap, sizeof(slot_t));
    if (!t->slots) { free(t); return NULL; }
    return t;
}

static void table_clear(table_t *t) {
    for (int64_t i = 0; i < t->cap; i++) {
        free(t->slots[i].key);
        free(t->slots[i].rest);
    }
    memset(t->slots, 0, (size_t)t->cap * sizeof(slot_t));
    t->count = 0;
}

void fb_table_free(table_t *t) {
    if (!t) return;
    table_clear(t);
    free(t->slots);
    free(t);
}

static slot_t *table_find_tag(table_t *t, uint64_t h, const uint8_t *head, int32_t hl, const uint8_t *kind,
                              int32_t kl, int32_t tag) {
    int64_t mask = t->cap - 1;
    for (int64_t i = (int64_t)(h & (uint64_t)mask);; i = (i + 1) & mask) {
        slot_t *s = &t->slots[i];
        if (!s->key) return s; /* the empty slot where it would go */
        if (s->hash == h && s->tag == tag && s->head_len == hl && s->kind_len == kl &&
            memcmp(s->key, head, (size_t)hl) == 0 && memcmp(s->key + hl, kind, (size_t)kl) == 0)
            return s;
    }
}

static slot_t *table_find(table_t *t, uint64_t h, const uint8_t *head, int32_t hl, const uint8_t *kind,
                          int32_t kl) {
    return table_find_tag(t, h, head, hl, kind, kl, 0);
}

static int table_grow(table_t *t) {
    int64_t cap = t->cap * 2;
    slot_t *old = t->slots, *slots = calloc((size_t)cap, sizeof(slot_t));
    if (!slots) return -1;
    int64_t old_cap = t->cap;
    t->slots = slots;
    t->cap = cap;
    for (int64_t i = 0; i < old_cap; i++) {
        if (!old[i].key) continue;
        int64_t j = (int64_t)(old[i].hash & (uint64_t)(cap - 1));
        while (slots[j].key) j = (j + 1) & (cap - 1);
        slots[j] = old[i];
    }
    free(old);
    return 0;
}

static int table_put_tag(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl,
                         const uint8_t *rest, int32_t rl, int32_t tag) {
    if (t->count >= MAX_RESTS) table_clear(t);
    if ((t->count + 1) * 2 > t->cap && table_grow(t) != 0) return -1;
    uint64_t h = key_hash(head, hl, kind, kl) ^ (uint64_t)tag * 0xD6E8FEB86659FD93ULL;
    slot_t *s = table_find_tag(t, h, head, hl, kind, kl, tag);
    uint8_t *key = malloc((size_t)hl + (size_t)kl + 1), *copy = malloc((size_t)rl + 1);
    if (!key || !copy) { free(key); free(copy); return -1; }
    memcpy(key, head, (size_t)hl);
    memcpy(key + hl, kind, (size_t)kl);
    memcpy(copy, rest, (size_t)rl);
    if (s->key) { free(s->key); free(s->rest); } else t->count++;
    s->hash = h; s->key = key; s->head_len = hl; s->kind_len = kl; s->rest = copy; s->rest_len = rl; s->tag = tag;
    return 0;
}

/* Remember a Log line; 0, or -1 out of memory. */
int fb_table_put(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl, const uint8_t *rest,
                 int32_t rl) {
    return table_put_tag(t, head, hl, kind, kl, rest, rl, 0);
}

/* ---- the batch ---------------------------------------------------------------------------- */
typedef struct {
    /* the samples: payload i is buf[offs[i]:offs[i+1]], its frame channel cids[i] (0: none yet) */
    const uint8_t *buf;
    const int64_t *offs;
    int64_t n;
    int32_t *cids;
    int32_t log_cid;   /* foxglove/log's channel; 0: not registered yet; -1: no Log lines */
    int32_t by_sim;    /* log time = origin + sim time; else = wall */
    int64_t origin, wall;
    uint32_t *seqs;    /* next sequence number by channel id */
    int64_t nseqs;
    table_t *rests;
    /* where the records go: out[0:out_len] (capacity out_cap), at chunk offset chunk_bytes */
    uint8_t *out;
    int64_t out_cap, out_len;
    int64_t chunk_bytes, chunk_messages, chunk_start, chunk_end, limit;
    /* index entries of the records written (capacity ix_cap) */
    int32_t *ix_cid;
    int64_t *ix_time, *ix_off;
    int64_t ix_cap, ix_len;
    /* the tally of the frames written: how many, log time span, noise items (flag per item) */
    int64_t frames, tmin, tmax, last_sim;
    uint8_t *noise;
    /* where it is: item, phase 1 = its frame written, its Log line next; and, for Python, the
     * item's head and kind (buf offsets) when it stopped for them; no_log: skip this Log */
    int64_t item;
    int32_t phase, no_log;
    int64_t head_at, head_len, kind_at, kind_len, log_time;
    struct records *recs; /* the records Python wrote already (NULL: every record is Python's) */
    int64_t records;      /* how many records were written here (flag 2 in noise[]) */
} batch_t;

static int lit_n(const uint8_t *p, int64_t n, int64_t *i, const char *s, size_t k) {
    if (*i + (int64_t)k > n || memcmp(p + *i, s, k) != 0) return 0;
    *i += (int64_t)k;
    return 1;
}
#define lit(p, n, i, s) lit_n(p, n, i, s, sizeof(s) - 1)

static int str_body(const uint8_t *p, int64_t n, int64_t *i) { /* [^"\\]* then the closing quote */
    while (*i < n && p[*i] != '"') {
        if (p[*i] == '\\') return 0;
        (*i)++;
    }
    if (*i >= n) return 0;
    (*i)++;
    return 1;
}

static int digits(const uint8_t *p, int64_t n, int64_t *i, uint64_t *value, int limit) {
    uint64_t v = 0;
    int64_t start = *i;
    while (*i < n && p[*i] >= '0' && p[*i] <= '9') {
        if (*i - start >= limit) return 0;
        if (value) v = v * 10 + (uint64_t)(p[*i] - '0');
        (*i)++;
    }
    if (*i == start) return 0;
    if (value) *value = v;
    return 1;
}

/* Recorder's _ENVELOPE_AT_START and the closing brace: the head's length, sim and wall times,
 * the kind's place; 0 if the payload is not so. */
static int parse(const uint8_t *p, int64_t n, int64_t *head_len, uint64_t *sim, uint64_t *pub, int64_t *kind_at,
                 int64_t *kind_len) {
    int64_t i = 0;
    if (n < 1 || p[n - 1] != '}') return 0;
    if (!lit(p, n, &i, "{\"link\":\"") || !str_body(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"src\":\"") || !str_body(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"dst\":\"") || !str_body(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"raw\":\"") || !str_body(p, n, &i)) return 0;
    *head_len = i;
    if (!lit(p, n, &i, ",\"sim_time_ns\":") || !digits(p, n, &i, sim, MAX_DIGITS)) return 0;
    if (!lit(p, n, &i, ",\"wall_time_ns\":") || !digits(p, n, &i, pub, MAX_DIGITS)) return 0;
    if (!lit(p, n, &i, ",\"seq\":") || !digits(p, n, &i, NULL, INT32_MAX)) return 0;
    if (!lit(p, n, &i, ",\"kind\":\"")) return 0;
    *kind_at = i;
    if (!str_body(p, n, &i)) return 0;
    *kind_len = i - 1 - *kind_at;
    return 1;
}

/* ---- records: (channel, bytes around the sim time) Python wrote, and each channel's coils ---- */
typedef struct records {
    table_t known;
    uint8_t **coils; /* by channel id: its last record's coils (NULL: none, the next is Python's) */
    int32_t *coils_len;
    int64_t ncoils;
} records_t;

records_t *fb_records_new(void) {
    records_t *r = calloc(1, sizeof *r);
    if (!r) return NULL;
    r->known.cap = 1024;
    r->known.slots = calloc((size_t)r->known.cap, sizeof(slot_t));
    if (!r->known.slots) { free(r); return NULL; }
    return r;
}

void fb_records_free(records_t *r) {
    if (!r) return;
    table_clear(&r->known);
    free(r->known.slots);
    for (int64_t i = 0; i < r->ncoils; i++) free(r->coils[i]);
    free(r->coils);
    free(r->coils_len);
    free(r);
}

static const uint8_t *find(const uint8_t *p, int64_t n, const char *s) {
    size_t k = strlen(s);
    for (int64_t i = 0; i + (int64_t)k <= n; i++)
        if (p[i] == (uint8_t)s[0] && memcmp(p + i, s, k) == 0) return p + i;
    return NULL;
}

/* A record's sim time digits: [*at, *at + *len), the value; 0 if it has not exactly one
 * "sim_time_ns": followed by digits and then , or } */
static int record_time(const uint8_t *p, int64_t n, int64_t *at, int64_t *len, uint64_t *sim) {
    const uint8_t *f = find(p, n, "\"sim_time_ns\":");
    if (!f) return 0;
    int64_t i = (f - p) + 14, start = i;
    if (!digits(p, n, &i, sim, MAX_DIGITS) || i >= n || (p[i] != ',' && p[i] != '}')) return 0;
    if ((p[start] == '0' && i - start > 1) || find(p + i, n - i, "\"sim_time_ns\":")) return 0;
    *at = start;
    *len = i - start;
    return 1;
}

/* The coils of a record's tail: from "joints_open": to ,"led_pos" (the mechanics' slice). */
static int record_coils(const uint8_t *tail, int64_t n, const uint8_t **at, int64_t *len) {
    const uint8_t *a = find(tail, n, "\"joints_open\":");
    if (!a) return 0;
    const uint8_t *e = find(a, n - (a - tail), ",\"led_pos\"");
    if (!e) return 0;
    *at = a;
    *len = e - a;
    return 1;
}

/* Python wrote record p[0:n] on channel cid: its coils are the channel's now, and (known) the
 * same bytes but the time may be written here from now on. 0, or -1 out of memory. */
int fb_record_seen(records_t *r, int32_t cid, const uint8_t *p, int64_t n, int32_t known) {
    if (cid <= 0) return 0;
    if (cid >= r->ncoils) {
        int64_t cap = cid * 2 + 16;
        uint8_t **c = realloc(r->coils, (size_t)cap * sizeof *c);
        if (!c) return -1;
        r->coils = c;
        int32_t *l = realloc(r->coils_len, (size_t)cap * sizeof *l);
        if (!l) return -1;
        r->coils_len = l;
        for (int64_t i = r->ncoils; i < cap; i++) { r->coils[i] = NULL; r->coils_len[i] = 0; }
        r->ncoils = cap;
    }
    free(r->coils[cid]);
    r->coils[cid] = NULL;
    int64_t at, len;
    uint64_t sim;
    const uint8_t *coils;
    int64_t coils_len;
    if (!record_time(p, n, &at, &len, &sim) || !record_coils(p + at + len, n - at - len, &coils, &coils_len))
        return 0;
    r->coils[cid] = malloc((size_t)coils_len + 1);
    if (!r->coils[cid]) return -1;
    memcpy(r->coils[cid], coils, (size_t)coils_len);
    r->coils_len[cid] = (int32_t)coils_len;
    if (!known) return 0;
    return table_put_tag(&r->known, p, (int32_t)at, p + at + len, (int32_t)(n - at - len), (const uint8_t *)"", 0,
                         cid);
}

static int varint(uint8_t *o, uint64_t v) {
    int k = 0;
    while (v > 0x7F) {
        o[k++] = (uint8_t)((v & 0x7F) | 0x80);
        v >>= 7;
    }
    o[k++] = (uint8_t)v;
    return k;
}

/* foxglove.timestamp_field: field 1 of a Foxglove message, a google.protobuf.Timestamp */
static int timestamp_field(uint8_t *o, uint64_t t) {
    uint64_t sec = t / 1000000000ULL, nsec = t % 1000000000ULL;
    int k = 2;
    if (sec) { o[k++] = 0x08; k += varint(o + k, sec); }
    if (nsec) { o[k++] = 0x10; k += varint(o + k, nsec); }
    o[0] = 0x0A;
    o[1] = (uint8_t)(k - 2);
    return k;
}

static void put_u16(uint8_t *o, uint32_t v) { o[0] = (uint8_t)v; o[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *o, uint32_t v) { for (int k = 0; k < 4; k++) o[k] = (uint8_t)(v >> (8 * k)); }
static void put_u64(uint8_t *o, uint64_t v) { for (int k = 0; k < 8; k++) o[k] = (uint8_t)(v >> (8 * k)); }

/* One message record at the end of out (room checked by the caller); 1 if the chunk is full. */
static int message(batch_t *b, int32_t cid, uint64_t log_time, uint64_t pub, const uint8_t *d1, int64_t n1,
                   const uint8_t *d2, int64_t n2) {
    uint8_t *o = b->out + b->out_len;
    int64_t len = n1 + n2;
    uint32_t seq = b->seqs[cid]++;
    o[0] = 0x05;
    put_u64(o + 1, (uint64_t)(MESSAGE_HEADER - 9 + len));
    put_u16(o + 9, (uint32_t)cid);
    put_u32(o + 11, seq);
    put_u64(o + 15, log_time);
    put_u64(o + 23, pub);
    memcpy(o + MESSAGE_HEADER, d1, (size_t)n1);
    if (n2) memcpy(o + MESSAGE_HEADER + n1, d2, (size_t)n2);
    if (b->chunk_messages == 0) b->chunk_start = b->chunk_end = (int64_t)log_time;
    else if ((int64_t)log_time < b->chunk_start) b->chunk_start = (int64_t)log_time;
    else if ((int64_t)log_time > b->chunk_end) b->chunk_end = (int64_t)log_time;
    b->ix_cid[b->ix_len] = cid;
    b->ix_time[b->ix_len] = (int64_t)log_time;
    b->ix_off[b->ix_len] = b->chunk_bytes;
    b->ix_len++;
    b->out_len += MESSAGE_HEADER + len;
    b->chunk_bytes += MESSAGE_HEADER + len;
    b->chunk_messages++;
    return b->chunk_bytes > b->limit;
}

static int room(batch_t *b, int64_t len) {
    return b->out_len + MESSAGE_HEADER + len <= b->out_cap && b->ix_len < b->ix_cap;
}

#define RECORD_CHUNK_FULL 100
/* A record Python wrote before but its time, with the channel's coils: written (0, or
 * RECORD_CHUNK_FULL if the chunk is full after it), or FB_NOT_FRAME (Python's), or what
 * Python must do first. */
static int record(batch_t *b, const uint8_t *p, int64_t n) {
    records_t *r = b->recs;
    int32_t cid = b->cids[b->item];
    int64_t at, len;
    uint64_t sim;
    const uint8_t *coils;
    int64_t coils_len;
    if (!r || cid <= 0 || cid >= r->ncoils || !r->coils[cid] || !record_time(p, n, &at, &len, &sim) ||
        sim >= MAX_TIME || (uint64_t)b->origin + sim >= (1ULL << 63))
        return FB_NOT_FRAME;
    const uint8_t *tail = p + at + len;
    int64_t tl = n - at - len;
    if (!record_coils(tail, tl, &coils, &coils_len) || coils_len != r->coils_len[cid] ||
        memcmp(coils, r->coils[cid], (size_t)coils_len) != 0)
        return FB_NOT_FRAME;
    uint64_t h = key_hash(p, (int32_t)at, tail, (int32_t)tl) ^ (uint64_t)cid * 0xD6E8FEB86659FD93ULL;
    if (!table_find_tag(&r->known, h, p, (int32_t)at, tail, (int32_t)tl, cid)->key) return FB_NOT_FRAME;
    if (cid >= b->nseqs) return FB_GROW_SEQS;
    if (!room(b, n)) return FB_OUT_FULL;
    int64_t log_time = b->by_sim ? b->origin + (int64_t)sim : b->wall;
    if ((int64_t)sim > b->last_sim) b->last_sim = (int64_t)sim;
    b->frames++;
    b->records++;
    if (b->frames == 1 || log_time < b->tmin) b->tmin = log_time;
    if (b->frames == 1 || log_time > b->tmax) b->tmax = log_time;
    b->noise[b->item] = 2;
    /* no wall_time_ns in it (Python knew these bytes): published at the batch's receive time */
    return message(b, cid, (uint64_t)log_time, (uint64_t)b->wall, p, n, NULL, 0) ? RECORD_CHUNK_FULL : 0;
}

int fb_frames(batch_t *b) {
    for (; b->item < b->n; b->item++) {
        const uint8_t *p = b->buf + b->offs[b->item];
        int64_t n = b->offs[b->item + 1] - b->offs[b->item];
        int64_t head_len, kind_at, kind_len;
        uint64_t sim, pub;
        /* a time from 2^62 on is no time (Recorder's MAX_TIME_NS): Python's careful path */
        if (!parse(p, n, &head_len, &sim, &pub, &kind_at, &kind_len) || sim >= MAX_TIME || pub >= MAX_TIME ||
            (uint64_t)b->origin + sim >= (1ULL << 63)) {
            if (b->phase) return -1; /* cannot happen: it parsed a moment ago */
            int code = record(b, p, n);
            if (code == 0) continue;
            if (code == RECORD_CHUNK_FULL) {
                b->item++;
                return FB_CHUNK_FULL;
            }
            return code;
        }
        int64_t log_time = b->by_sim ? b->origin + (int64_t)sim : b->wall;
        b->head_at = b->offs[b->item];
        b->head_len = head_len;
        b->kind_at = b->offs[b->item] + kind_at;
        b->kind_len = kind_len;
        b->log_time = log_time;
        if (b->phase == 0) {
            int32_t cid = b->cids[b->item];
            if (cid == 0) return FB_NEW_CHANNEL;
            if (cid >= b->nseqs) return FB_GROW_SEQS;
            if (!room(b, n)) return FB_OUT_FULL;
            if ((int64_t)sim > b->last_sim) b->last_sim = (int64_t)sim;
            b->frames++;
            if (b->frames == 1 || log_time < b->tmin) b->tmin = log_time;
            if (b->frames == 1 || log_time > b->tmax) b->tmax = log_time;
            if (kind_len == 5 && memcmp(p + kind_at, "noise", 5) == 0) b->noise[b->item] = 1;
            b->phase = 1;
            b->no_log = 0;
            if (message(b, cid, (uint64_t)log_time, pub, p, n, NULL, 0)) return FB_CHUNK_FULL;
        }
        /* phase 1: its Log line */
        if (b->log_cid >= 0 && !b->no_log) {
            uint64_t h = key_hash(p, (int32_t)head_len, p + kind_at, (int32_t)kind_len);
            slot_t *s = table_find(b->rests, h, p, (int32_t)head_len, p + kind_at, (int32_t)kind_len);
            if (!s->key) return FB_REST_MISS;
            if (b->log_cid == 0) return FB_NEW_LOG_CHANNEL;
            if (b->log_cid >= b->nseqs) return FB_GROW_SEQS;
            uint8_t stamp[32];
            int sl = timestamp_field(stamp, (uint64_t)log_time);
            if (!room(b, sl + s->rest_len)) return FB_OUT_FULL;
            b->phase = 0;
            if (message(b, b->log_cid, (uint64_t)log_time, (uint64_t)log_time, stamp, sl, s->rest, s->rest_len)) {
                b->item++;
                return FB_CHUNK_FULL;
            }
        }
        b->phase = 0;
    }
    return FB_DONE;
}

/* A chunk's MessageIndex records: one per channel, in the order of the channel's first message,
 * its (log time, offset) pairs in message order. out: capacity 15 * channels + 16 * n; per
 * channel, in that order, its id in chan[] and its record's offset from out's start in at[].
 * Returns the number of channels, -1 out of memory. */
int64_t fb_index(const int32_t *cid, const int64_t *t, const int64_t *off, int64_t n, uint8_t *out,
                 int32_t *chan, int64_t *at, int64_t *out_len) {
    int32_t max = 0;
    for (int64_t i = 0; i < n; i++) if (cid[i] > max) max = cid[i];
    int64_t *count = calloc((size_t)max + 1, sizeof(int64_t)), *pos = calloc((size_t)max + 1, sizeof(int64_t));
    if (!count || !pos) { free(count); free(pos); return -1; }
    int64_t channels = 0;
    for (int64_t i = 0; i < n; i++) if (count[cid[i]]++ == 0) chan[channels++] = cid[i];
    int64_t o = 0;
    for (int64_t c = 0; c < channels; c++) {
        int32_t id = chan[c];
        int64_t k = count[id];
        at[c] = o;
        out[o] = 0x07;
        put_u64(out + o + 1, (uint64_t)(6 + 16 * k));
        put_u16(out + o + 9, (uint32_t)id);
        put_u32(out + o + 11, (uint32_t)(16 * k));
        pos[id] = o + 15;
        o += 15 + 16 * k;
    }
    for (int64_t i = 0; i < n; i++) {
        put_u64(out + pos[cid[i]], (uint64_t)t[i]);
        put_u64(out + pos[cid[i]] + 8, (uint64_t)off[i]);
        pos[cid[i]] += 16;
    }
    *out_len = o;
    free(count);
    free(pos);
    return channels;
}

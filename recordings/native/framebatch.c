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
#define _GNU_SOURCE /* memmem */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

enum {
    FB_DONE = 0, FB_NOT_FRAME = 1, FB_NEW_CHANNEL = 2, FB_NEW_LOG_CHANNEL = 3, FB_REST_MISS = 4,
    FB_CHUNK_FULL = 5, FB_OUT_FULL = 6, FB_GROW_SEQS = 7, FB_NEW_SCENE_CHANNEL = 12,
};

#define MESSAGE_HEADER 31 /* opcode, record length, channel, sequence, log time, publish time */
#define MAX_DIGITS 19     /* a longer time is left to Python (which has big integers) */
#define MAX_TIME (1ULL << 62)

/* ---- the Log lines already seen: (head, kind) -> the encoded Log without its timestamp ---- */
typedef struct {
    uint64_t hash;
    uint8_t *key; /* head, then kind */
    int32_t head_len, kind_len, tag; /* tag: what the entry is (TAG_*) */
    uint8_t *rest;
    int32_t rest_len;
    int64_t id; /* a key's number (TAG_KEY), a kind's count (TAG_KIND) */
} slot_t;

/* What a table entry is: the tables of Log lines (rests) and of records share one layout. */
enum { TAG_LOG = 0, TAG_TAIL = -2, TAG_KEY = -3, TAG_KIND = -4, TAG_DESCRIBE = -5, TAG_SCENE = -6 };

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

/* The tables are never cleared: the Log lines are what the recorder's Python path reads too
 * (FrameLog asks here first), so a line once made stays the line of its frame. */
static slot_t *table_put_tag(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl,
                             const uint8_t *rest, int32_t rl, int32_t tag) {
    if ((t->count + 1) * 2 > t->cap && table_grow(t) != 0) return NULL;
    uint64_t h = key_hash(head, hl, kind, kl) ^ (uint64_t)tag * 0xD6E8FEB86659FD93ULL;
    slot_t *s = table_find_tag(t, h, head, hl, kind, kl, tag);
    uint8_t *key = malloc((size_t)hl + (size_t)kl + 1), *copy = malloc((size_t)rl + 1);
    if (!key || !copy) { free(key); free(copy); return NULL; }
    memcpy(key, head, (size_t)hl);
    memcpy(key + hl, kind, (size_t)kl);
    memcpy(copy, rest, (size_t)rl);
    if (s->key) { free(s->key); free(s->rest); } else { t->count++; s->id = 0; }
    s->hash = h; s->key = key; s->head_len = hl; s->kind_len = kl; s->rest = copy; s->rest_len = rl; s->tag = tag;
    return s;
}

static uint64_t tag_hash(const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl, int32_t tag) {
    return key_hash(head, hl, kind, kl) ^ (uint64_t)(int64_t)tag * 0xD6E8FEB86659FD93ULL;
}

static slot_t *table_get(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl, int32_t tag) {
    slot_t *s = table_find_tag(t, tag_hash(head, hl, kind, kl, tag), head, hl, kind, kl, tag);
    return s->key ? s : NULL;
}

/* Remember a Log line; 0, or -1 out of memory. */
int fb_table_put(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl, const uint8_t *rest,
                 int32_t rl) {
    return table_put_tag(t, head, hl, kind, kl, rest, rl, TAG_LOG) ? 0 : -1;
}

/* The Log line of (head, kind) into out if it fits in cap bytes: its length, -1 if unknown. */
int64_t fb_table_get(table_t *t, const uint8_t *head, int32_t hl, const uint8_t *kind, int32_t kl, uint8_t *out,
                     int64_t cap) {
    slot_t *s = table_get(t, head, hl, kind, kl, TAG_LOG);
    if (!s) return -1;
    if (s->rest_len <= cap) memcpy(out, s->rest, (size_t)s->rest_len);
    return s->rest_len;
}

/* realloc field to cap elements, or return -1 (out of memory) */
#define GROW(field, cap)                                                   \
    do {                                                                   \
        void *grown_ = realloc((void *)(field), (size_t)(cap) * sizeof *(field)); \
        if (!grown_) return -1;                                            \
        (field) = grown_;                                                  \
    } while (0)

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
    /* fb_packed: the batch in bus.transport.pack_batch's bytes, the sample at pos (its key's
     * entry key_id when it stopped), the recorder's keys; kinds counted by event kind */
    const uint8_t *packed;
    int64_t packed_len, pos, key_id, samples;
    struct keys *keys;
    table_t *kinds;
    int64_t events;
    /* foxglove/scene's channel (0: not registered yet, -1: no scene); a coil change's scene
     * message waiting behind a full chunk (phase 2) */
    int32_t scene_cid;
    const uint8_t *scene_rest;
    int64_t scene_rest_len;
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
    table_t known;   /* tails (TAG_TAIL): a record's bytes after its time, checked by Python */
    uint8_t **coils; /* by channel id: its last record's coils (NULL: none, the next is Python's) */
    int32_t *coils_len;
    uint8_t **heads; /* by channel id: {"module":"<its module>","sim_time_ns": once Python saw it */
    int32_t *heads_len;
    /* the scene, by channel id: the look of the channel's module apart from its coils (0: the
     * next coil change is Python's, -1: not placed, drawn nowhere); the last record written
     * here (its tail in known, its time) since Python last asked (changed) */
    int32_t *look;
    const uint8_t **last_tail;
    int32_t *last_tail_len;
    int64_t *last_sim;
    int32_t *changed, *listed; /* the channels changed (each listed once) */
    int64_t nchanged;
    table_t scene; /* (look, coils) -> the entity's encoding after its timestamp (TAG_SCENE) */
    int64_t ncoils;
} records_t;

records_t *fb_records_new(void) {
    records_t *r = calloc(1, sizeof *r);
    if (!r) return NULL;
    r->known.cap = 1024;
    r->known.slots = calloc((size_t)r->known.cap, sizeof(slot_t));
    r->scene.cap = 1024;
    r->scene.slots = calloc((size_t)r->scene.cap, sizeof(slot_t));
    if (!r->known.slots || !r->scene.slots) { free(r->known.slots); free(r->scene.slots); free(r); return NULL; }
    return r;
}

void fb_records_free(records_t *r) {
    if (!r) return;
    table_clear(&r->known);
    free(r->known.slots);
    for (int64_t i = 0; i < r->ncoils; i++) { free(r->coils[i]); free(r->heads[i]); }
    free(r->coils);
    free(r->coils_len);
    free(r->heads);
    free(r->heads_len);
    free(r->look); free(r->last_tail); free(r->last_tail_len); free(r->last_sim); free(r->changed); free(r->listed);
    table_clear(&r->scene);
    free(r->scene.slots);
    free(r);
}

static const uint8_t *find(const uint8_t *p, int64_t n, const char *s) {
    return n > 0 ? memmem(p, (size_t)n, s, strlen(s)) : NULL;
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

/* Python wrote record p[0:n] on channel cid: its coils are the channel's now, and (known) its
 * head ({"module":"<the channel's module>","sim_time_ns":, checked by Python) is the channel's
 * and its tail (the bytes after its time) one that any channel's record may end with: Python's
 * careful path would write such a record, count it by topic and derive nothing but from its
 * coils (a tail naming no module, no other time and no wall time: it means the same after any
 * module's head). 0, or -1 out of memory. */
int fb_record_seen(records_t *r, int32_t cid, const uint8_t *p, int64_t n, int32_t known) {
    if (cid <= 0) return 0;
    if (cid >= r->ncoils) {
        int64_t cap = cid * 2 + 16;
        GROW(r->coils, cap);
        GROW(r->coils_len, cap);
        GROW(r->heads, cap);
        GROW(r->heads_len, cap);
        GROW(r->look, cap);
        GROW(r->last_tail, cap);
        GROW(r->last_tail_len, cap);
        GROW(r->last_sim, cap);
        GROW(r->changed, cap);
        GROW(r->listed, cap);
        for (int64_t i = r->ncoils; i < cap; i++) {
            r->coils[i] = r->heads[i] = NULL;
            r->coils_len[i] = r->heads_len[i] = r->look[i] = r->last_tail_len[i] = r->listed[i] = 0;
            r->last_tail[i] = NULL;
            r->last_sim[i] = -1;
        }
        r->ncoils = cap;
    }
    free(r->coils[cid]);
    r->coils[cid] = NULL;
    r->last_sim[cid] = -1; /* Python's record is the scene's now */
    int64_t at, len;
    uint64_t sim;
    const uint8_t *coils;
    int64_t coils_len;
    if (!record_time(p, n, &at, &len, &sim) || !record_coils(p + at + len, n - at - len, &coils, &coils_len)) {
        r->look[cid] = 0; /* its next record is Python's, scene and all */
        return 0;
    }
    r->coils[cid] = malloc((size_t)coils_len + 1);
    if (!r->coils[cid]) return -1;
    memcpy(r->coils[cid], coils, (size_t)coils_len);
    r->coils_len[cid] = (int32_t)coils_len;
    const uint8_t *tail = p + at + len;
    int64_t tl = n - at - len;
    if (!known || find(tail, tl, "\"module\"") || find(tail, tl, "\"wall_time_ns\"")) return 0;
    if (!r->heads[cid] || r->heads_len[cid] != at || memcmp(r->heads[cid], p, (size_t)at) != 0) {
        free(r->heads[cid]);
        r->heads[cid] = malloc((size_t)at + 1);
        if (!r->heads[cid]) return -1;
        memcpy(r->heads[cid], p, (size_t)at);
        r->heads_len[cid] = (int32_t)at;
    }
    if (table_get(&r->known, tail, (int32_t)tl, (const uint8_t *)"", 0, TAG_TAIL)) return 0;
    return table_put_tag(&r->known, tail, (int32_t)tl, (const uint8_t *)"", 0, (const uint8_t *)"", 0, TAG_TAIL)
        ? 0 : -1;
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
#define RECORD_COILS 101
#define RECORD_SCENE_NEXT 102

/* SceneView._one: a SceneUpdate of one entity (field 2) whose encoding is the timestamp, then
 * the rest (scene_rest); 1 if the chunk is full after it. */
static int scene_message(batch_t *b) {
    uint8_t head[48];
    int ts_len = timestamp_field(head + 12, (uint64_t)b->log_time);
    uint8_t pre[16];
    int k = 0;
    pre[k++] = 0x12;
    k += varint(pre + k, (uint64_t)(ts_len + b->scene_rest_len));
    memmove(head + 12 - k, pre, (size_t)k);
    return message(b, b->scene_cid, (uint64_t)b->log_time, (uint64_t)b->log_time, head + 12 - k, k + ts_len,
                   b->scene_rest, b->scene_rest_len);
}
/* A record Python wrote before but its time, with the channel's coils: written (0, or
 * RECORD_CHUNK_FULL if the chunk is full after it), or FB_NOT_FRAME (Python's), or what
 * Python must do first. With coils: the same record with other coils than the channel's last
 * (a coil change) is written too, and RECORD_COILS says Python must feed the scene with it. */
static int record(batch_t *b, int32_t cid, const uint8_t *p, int64_t n, int coils_too) {
    records_t *r = b->recs;
    int64_t at, len;
    uint64_t sim;
    const uint8_t *coils;
    int64_t coils_len;
    if (!r || cid <= 0 || cid >= r->ncoils || !record_time(p, n, &at, &len, &sim) || sim >= MAX_TIME ||
        (uint64_t)b->origin + sim >= (1ULL << 63))
        return FB_NOT_FRAME;
    const uint8_t *tail = p + at + len;
    int64_t tl = n - at - len;
    if (!r->heads[cid] || r->heads_len[cid] != at || memcmp(p, r->heads[cid], (size_t)at) != 0)
        return FB_NOT_FRAME;
    int same = r->coils[cid] && record_coils(tail, tl, &coils, &coils_len) && coils_len == r->coils_len[cid] &&
               memcmp(coils, r->coils[cid], (size_t)coils_len) == 0;
    if (!same && !coils_too) return FB_NOT_FRAME;
    slot_t *known = table_get(&r->known, tail, (int32_t)tl, (const uint8_t *)"", 0, TAG_TAIL);
    if (!known) return FB_NOT_FRAME;
    if (cid >= b->nseqs) return FB_GROW_SEQS;
    if (!room(b, n)) return FB_OUT_FULL;
    /* a coil change C draws: the module's look is known here and its entity with these coils */
    slot_t *drawn = NULL;
    int look = !same && r->look[cid] != 0 && b->packed && record_coils(tail, tl, &coils, &coils_len);
    if (look && r->look[cid] > 0) {
        uint8_t key[512];
        if (coils_len + 4 > (int64_t)sizeof key) look = 0;
        else {
            memcpy(key, &r->look[cid], 4);
            memcpy(key + 4, coils, (size_t)coils_len);
            drawn = table_get(&r->scene, key, (int32_t)(coils_len + 4), (const uint8_t *)"", 0, TAG_SCENE);
            if (!drawn) look = 0;
            else if (b->scene_cid == 0) return FB_NEW_SCENE_CHANNEL;
            else if (b->scene_cid < 0 || b->scene_cid >= b->nseqs) look = 0;
            else if (!room(b, n + MESSAGE_HEADER + 32 + drawn->rest_len) || b->ix_len + 2 > b->ix_cap) return FB_OUT_FULL;
        }
    }
    int64_t log_time = b->by_sim ? b->origin + (int64_t)sim : b->wall;
    if ((int64_t)sim > b->last_sim) b->last_sim = (int64_t)sim;
    b->frames++;
    b->records++;
    if (b->frames == 1 || log_time < b->tmin) b->tmin = log_time;
    if (b->frames == 1 || log_time > b->tmax) b->tmax = log_time;
    if (!b->packed) b->noise[b->item] = 2;
    /* no wall_time_ns in it (Python knew these bytes): published at the batch's receive time;
     * after a coil change Python closes a full chunk before it writes the scene's message */
    int full = message(b, cid, (uint64_t)log_time, (uint64_t)b->wall, p, n, NULL, 0);
    if (!same && !look) return RECORD_COILS;
    if (!same) { /* the channel's coils and last record are these now; the scene's update follows */
        uint8_t *copy = malloc((size_t)coils_len + 1);
        if (!copy) return -1;
        memcpy(copy, coils, (size_t)coils_len);
        free(r->coils[cid]);
        r->coils[cid] = copy;
        r->coils_len[cid] = (int32_t)coils_len;
        if (!r->listed[cid]) { r->listed[cid] = 1; r->changed[r->nchanged++] = cid; }
        r->last_tail[cid] = known->key;
        r->last_tail_len[cid] = known->head_len;
        r->last_sim[cid] = (int64_t)sim;
        if (drawn) {
            b->scene_rest = drawn->rest;
            b->scene_rest_len = drawn->rest_len;
            b->log_time = log_time;
            if (full) return RECORD_SCENE_NEXT;
            return scene_message(b) ? RECORD_CHUNK_FULL : 0;
        }
    }
    return full ? RECORD_CHUNK_FULL : 0;
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
            int code = record(b, b->cids[b->item], p, n, 0);
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

/* The look of channel cid's module apart from its coils (SceneView's), as Python knows it now:
 * look > 0 one Python numbered, -1 not placed, 0 unknown (the next coil change is Python's). */
int fb_scene_look(records_t *r, int32_t cid, int32_t look) {
    if (cid <= 0) return 0;
    if (cid >= r->ncoils && fb_record_seen(r, cid, (const uint8_t *)"", 0, 0) != 0) return -1;
    r->look[cid] = look;
    return 0;
}

/* The entity's encoding after its timestamp for look with the coils of record p (Python drew
 * it); 0, or -1 out of memory (1: p has no coils). */
int fb_scene_put(records_t *r, int32_t look, const uint8_t *p, int64_t n, const uint8_t *rest, int32_t rl) {
    int64_t at, len;
    uint64_t sim;
    const uint8_t *coils;
    int64_t coils_len;
    if (!record_time(p, n, &at, &len, &sim) || !record_coils(p + at + len, n - at - len, &coils, &coils_len) ||
        coils_len + 4 > 512)
        return 1;
    uint8_t key[512];
    memcpy(key, &look, 4);
    memcpy(key + 4, coils, (size_t)coils_len);
    return table_put_tag(&r->scene, key, (int32_t)(coils_len + 4), (const uint8_t *)"", 0, rest, rl, TAG_SCENE) ? 0
                                                                                                                   : -1;
}

/* The channels whose coils changed here since the last call: their ids, last records' times
 * and tails (pointer, length), at most max of them (the rest at the next call); how many. */
int64_t fb_scene_changed(records_t *r, int32_t *cids, int64_t *sims, const uint8_t **tails, int32_t *lens,
                         int64_t max) {
    int64_t m = 0, i = 0;
    for (; i < r->nchanged && m < max; i++) {
        int32_t cid = r->changed[i];
        r->listed[cid] = 0;
        if (r->last_sim[cid] < 0) continue; /* Python wrote the channel since */
        cids[m] = cid; sims[m] = r->last_sim[cid]; tails[m] = r->last_tail[cid]; lens[m] = r->last_tail_len[cid];
        r->last_sim[cid] = -1;
        m++;
    }
    memmove(r->changed, r->changed + i, (size_t)(r->nchanged - i) * sizeof *r->changed);
    r->nchanged -= i;
    return m;
}

/* ==== packed batches (Recorder.write_packed) ================================================
 *
 * fb_packed() writes a batch in bus.transport.pack_batch's bytes: per sample, its key's entry in
 * the recorder's key table says how (FB_KEY_*, set by Python when the key first came) and on
 * which channel. Frames as fb_frames writes them, each with its Log line, which is made here
 * when the line of its (link, src, dst, raw, kind) is not known yet but the describe text of
 * its (link, kind, raw, view) is (a text Python made once from an envelope of exactly these
 * bytes): Python's FrameLog would make the same line from the same fields. Actuator records as
 * record() writes them; events and light (ir keys) as the careful path and the fast path of
 * Python would, where the bytes leave no doubt (anything unusual is Python's). Counts by key
 * and by event kind stay here until Python folds them into its tally. */

enum { FB_KEY_PYTHON = 0, FB_KEY_FRAME = 1, FB_KEY_RECORD = 2, FB_KEY_FAST = 3, FB_KEY_EVENT = 4 };
enum { FB_NEW_KEY = 8, FB_PYTHON = 9, FB_BAD_BATCH = 10, FB_COILS = 11 };

typedef struct keys {
    table_t t;              /* key bytes -> entry (slot id) */
    int32_t *cls, *cid;     /* by entry */
    int64_t *count, *noise; /* samples written here by entry, noise frames among them */
    int64_t n, cap;
} keys_t;

keys_t *fb_keys_new(void) {
    keys_t *k = calloc(1, sizeof *k);
    if (!k) return NULL;
    k->t.cap = 1024;
    k->t.slots = calloc((size_t)k->t.cap, sizeof(slot_t));
    if (!k->t.slots) { free(k); return NULL; }
    return k;
}

void fb_keys_free(keys_t *k) {
    if (!k) return;
    table_clear(&k->t);
    free(k->t.slots);
    free(k->cls); free(k->cid); free(k->count); free(k->noise);
    free(k);
}

/* A key's entry: its number, or -1 out of memory. */
int64_t fb_key_put(keys_t *k, const uint8_t *key, int32_t len, int32_t cls, int32_t cid) {
    if (k->n == k->cap) {
        int64_t cap = k->cap * 2 + 64;
        GROW(k->cls, cap);
        GROW(k->cid, cap);
        GROW(k->count, cap);
        GROW(k->noise, cap);
        k->cap = cap;
    }
    slot_t *s = table_put_tag(&k->t, key, len, (const uint8_t *)"", 0, (const uint8_t *)"", 0, TAG_KEY);
    if (!s) return -1;
    s->id = k->n;
    k->cls[k->n] = cls;
    k->cid[k->n] = cid;
    k->count[k->n] = k->noise[k->n] = 0;
    return k->n++;
}

void fb_key_set_cid(keys_t *k, int64_t id, int32_t cid) {
    if (id >= 0 && id < k->n) k->cid[id] = cid;
}

/* A new file: no key has a channel in it yet. */
void fb_keys_new_file(keys_t *k) {
    for (int64_t i = 0; i < k->n; i++) k->cid[i] = 0;
}

/* The entries with samples counted since the last call, into ids/counts/noise (room for every
 * entry); how many. The counts start again from zero. */
int64_t fb_key_counts(keys_t *k, int64_t *ids, int64_t *counts, int64_t *noise) {
    int64_t m = 0;
    for (int64_t i = 0; i < k->n; i++) {
        if (!k->count[i]) continue;
        ids[m] = i; counts[m] = k->count[i]; noise[m] = k->noise[i];
        m++;
        k->count[i] = k->noise[i] = 0;
    }
    return m;
}

/* The event kinds counted since the last call: "kind\0" then its count as 8 bytes, each, into
 * out (capacity cap); the length written, or -1 if out is too small (nothing is lost then). */
int64_t fb_kind_counts(table_t *t, uint8_t *out, int64_t cap) {
    int64_t need = 0;
    for (int64_t i = 0; i < t->cap; i++)
        if (t->slots[i].key && t->slots[i].id) need += t->slots[i].head_len + 9;
    if (need > cap) return -1;
    int64_t o = 0;
    for (int64_t i = 0; i < t->cap; i++) {
        slot_t *s = &t->slots[i];
        if (!s->key || !s->id) continue;
        memcpy(out + o, s->key, (size_t)s->head_len);
        o += s->head_len;
        out[o++] = 0;
        put_u64(out + o, (uint64_t)s->id);
        o += 8;
        s->id = 0;
    }
    return o;
}

/* ---- describe texts: (link, kind, raw, view) -> Frame.describe() of such an envelope ---- */
static int64_t describe_key(uint8_t *o, const uint8_t *p, int64_t link_at, int64_t link_len, int64_t kind_at,
                            int64_t kind_len, int64_t raw_at, int64_t raw_len, int64_t view_at, int64_t view_len) {
    int64_t k = 0;
    memcpy(o + k, p + link_at, (size_t)link_len); k += link_len; o[k++] = 0;
    memcpy(o + k, p + kind_at, (size_t)kind_len); k += kind_len; o[k++] = 0;
    memcpy(o + k, p + raw_at, (size_t)raw_len); k += raw_len; o[k++] = 0;
    memcpy(o + k, p + view_at, (size_t)view_len); k += view_len;
    return k;
}

/* An envelope's bytes from head on, as Envelope.to_json writes them and JSON reads them back
 * exactly (printable ASCII strings, lowercase hex, integers without leading zeros, the fields
 * in their order): where its link, src, dst, raw and view are; 0 if it is not so. */
typedef struct { int64_t link_at, link_len, src_at, src_len, dst_at, dst_len, raw_at, raw_len, view_at, view_len; } env_t;

static int plain(const uint8_t *p, int64_t a, int64_t b) { /* printable ASCII, no quote or backslash */
    for (int64_t i = a; i < b; i++) if (p[i] < 0x20 || p[i] > 0x7E || p[i] == '"' || p[i] == '\\') return 0;
    return 1;
}

static int canon_int(const uint8_t *p, int64_t n, int64_t *i) { /* JSON's non-negative integer */
    int64_t start = *i;
    if (!digits(p, n, i, NULL, MAX_DIGITS)) return 0;
    return !(p[start] == '0' && *i - start > 1);
}

static int null_or_int(const uint8_t *p, int64_t n, int64_t *i) {
    return lit(p, n, i, "null") || canon_int(p, n, i);
}

static int canonical_envelope(const uint8_t *p, int64_t n, env_t *e) {
    int64_t i = 0;
    if (!lit(p, n, &i, "{\"link\":\"")) return 0;
    e->link_at = i;
    if (!str_body(p, n, &i)) return 0;
    e->link_len = i - 1 - e->link_at;
    if (!lit(p, n, &i, ",\"src\":\"")) return 0;
    e->src_at = i;
    if (!str_body(p, n, &i)) return 0;
    e->src_len = i - 1 - e->src_at;
    if (!lit(p, n, &i, ",\"dst\":\"")) return 0;
    e->dst_at = i;
    if (!str_body(p, n, &i)) return 0;
    e->dst_len = i - 1 - e->dst_at;
    if (!lit(p, n, &i, ",\"raw\":\"")) return 0;
    e->raw_at = i;
    if (!str_body(p, n, &i)) return 0;
    e->raw_len = i - 1 - e->raw_at;
    if (!lit(p, n, &i, ",\"sim_time_ns\":") || !canon_int(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"wall_time_ns\":") || !canon_int(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"seq\":") || !canon_int(p, n, &i)) return 0;
    if (!lit(p, n, &i, ",\"kind\":\"")) return 0;
    int64_t kind_at = i;
    if (!str_body(p, n, &i) || !plain(p, kind_at, i - 1)) return 0;
    if (!lit(p, n, &i, ",\"view\":")) return 0;
    e->view_at = i;
    /* the last ,"first_byte_ns": is the field's (what follows it holds no quote-comma) */
    static const char fb[] = ",\"first_byte_ns\":";
    int64_t at = -1;
    for (int64_t j = n - (int64_t)sizeof fb + 1; j >= i; j--)
        if (p[j] == ',' && memcmp(p + j, fb, sizeof fb - 1) == 0) { at = j; break; }
    if (at < 0) return 0;
    e->view_len = at - i;
    i = at + (int64_t)sizeof fb - 1;
    if (!null_or_int(p, n, &i) || !lit(p, n, &i, ",\"origin\":\"")) return 0;
    int64_t origin_at = i;
    if (!str_body(p, n, &i) || !plain(p, origin_at, i - 1)) return 0;
    if (!lit(p, n, &i, ",\"channel\":") || !null_or_int(p, n, &i) || !lit(p, n, &i, ",\"v\":") || !canon_int(p, n, &i))
        return 0;
    if (i != n - 1 || p[i] != '}' || e->view_len < 2) return 0;
    if (!plain(p, e->link_at, e->link_at + e->link_len) || !plain(p, e->src_at, e->src_at + e->src_len) ||
        !plain(p, e->dst_at, e->dst_at + e->dst_len) || (e->raw_len & 1))
        return 0;
    for (int64_t j = e->raw_at; j < e->raw_at + e->raw_len; j++)
        if (!((p[j] >= '0' && p[j] <= '9') || (p[j] >= 'a' && p[j] <= 'f'))) return 0;
    return 1;
}

/* Remember describe text for envelopes with p's (link, kind, raw, view) (p: one such envelope,
 * canonical); 0, 1 if p is no canonical envelope (nothing remembered), -1 out of memory. */
int fb_describe_put(table_t *t, const uint8_t *p, int64_t n, const uint8_t *text, int32_t tl) {
    env_t e;
    int64_t head_len, kind_at, kind_len;
    uint64_t sim, pub;
    if (!parse(p, n, &head_len, &sim, &pub, &kind_at, &kind_len) || !canonical_envelope(p, n, &e)) return 1;
    uint8_t *key = malloc((size_t)n + 4);
    if (!key) return -1;
    int64_t kl = describe_key(key, p, e.link_at, e.link_len, kind_at, kind_len, e.raw_at, e.raw_len, e.view_at,
                              e.view_len);
    slot_t *s = table_put_tag(t, key, (int32_t)kl, (const uint8_t *)"", 0, text, tl, TAG_DESCRIBE);
    free(key);
    return s ? 0 : -1;
}

static int put_varint_field(uint8_t *o, uint8_t tag, const uint8_t *d, int64_t n) {
    int k = 0;
    o[k++] = tag;
    k += varint(o + k, (uint64_t)n);
    memcpy(o + k, d, (size_t)n);
    return k + (int)n;
}

/* FrameLog.rest of a canonical envelope whose describe text is known: the Log without its
 * timestamp (level, message "src → dst  describe  [raw]", name "link/src") into the rest
 * table under (head, kind); the slot, or NULL (not known, or out of memory). */
static slot_t *compose(batch_t *b, const uint8_t *p, int64_t n, int64_t head_len, int64_t kind_at, int64_t kind_len) {
    env_t e;
    if (!canonical_envelope(p, n, &e)) return NULL;
    int64_t kl_max = n + 4;
    uint8_t stack[512], *key = kl_max <= (int64_t)sizeof stack ? stack : malloc((size_t)kl_max);
    if (!key) return NULL;
    int64_t kl = describe_key(key, p, e.link_at, e.link_len, kind_at, kind_len, e.raw_at, e.raw_len, e.view_at,
                              e.view_len);
    slot_t *d = table_get(b->rests, key, (int32_t)kl, (const uint8_t *)"", 0, TAG_DESCRIBE);
    if (key != stack) free(key);
    if (!d) return NULL;
    int64_t msg_len = e.src_len + 5 + e.dst_len + 2 + d->rest_len + 3 + e.raw_len + 1;
    int64_t name_len = e.link_len + 1 + e.src_len;
    uint8_t *msg = malloc((size_t)(msg_len + name_len + 32) * 2);
    if (!msg) return NULL;
    uint8_t *name = msg + msg_len, *rest = name + name_len;
    int64_t k = 0;
    memcpy(msg + k, p + e.src_at, (size_t)e.src_len); k += e.src_len;
    memcpy(msg + k, " \xe2\x86\x92 ", 5); k += 5; /* " → " */
    memcpy(msg + k, p + e.dst_at, (size_t)e.dst_len); k += e.dst_len;
    memcpy(msg + k, "  ", 2); k += 2;
    memcpy(msg + k, d->rest, (size_t)d->rest_len); k += d->rest_len;
    memcpy(msg + k, "  [", 3); k += 3;
    memcpy(msg + k, p + e.raw_at, (size_t)e.raw_len); k += e.raw_len;
    msg[k++] = ']';
    memcpy(name, p + e.link_at, (size_t)e.link_len);
    name[e.link_len] = '/';
    memcpy(name + e.link_len + 1, p + e.src_at, (size_t)e.src_len);
    int64_t r = 0;
    rest[r++] = 0x10; /* level: Info 2, Warning 3 (noise) */
    rest[r++] = (kind_len == 5 && memcmp(p + kind_at, "noise", 5) == 0) ? 3 : 2;
    r += put_varint_field(rest + r, 0x1A, msg, msg_len);
    if (name_len) r += put_varint_field(rest + r, 0x22, name, name_len);
    slot_t *s = table_put_tag(b->rests, p, (int32_t)head_len, p + kind_at, (int32_t)kind_len, rest, (int32_t)r, TAG_LOG);
    free(msg);
    return s;
}

/* ---- events: a JSON object Python's decoder reads as this does ---------------------------- */
#define JSON_DEPTH 32
typedef struct { int64_t kind_at, kind_len, sim_at, sim_len, wall_at, wall_len; } event_t;

static void ws(const uint8_t *p, int64_t n, int64_t *i) {
    while (*i < n && (p[*i] == ' ' || p[*i] == '\t' || p[*i] == '\n' || p[*i] == '\r')) (*i)++;
}

static int hexdigit(uint8_t c) { return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f') || (c >= 'A' && c <= 'F'); }

/* A JSON string from its opening quote (ASCII only: anything else is left to Python); *escaped
 * set if it has an escape. */
static int json_string(const uint8_t *p, int64_t n, int64_t *i, int *escaped) {
    if (*i >= n || p[*i] != '"') return 0;
    (*i)++;
    *escaped = 0;
    while (*i < n) {
        uint8_t c = p[*i];
        if (c == '"') { (*i)++; return 1; }
        if (c < 0x20 || c > 0x7E) return 0;
        if (c == '\\') {
            *escaped = 1;
            if (*i + 1 >= n) return 0;
            uint8_t e = p[*i + 1];
            if (e == 'u') {
                if (*i + 5 >= n || !hexdigit(p[*i + 2]) || !hexdigit(p[*i + 3]) || !hexdigit(p[*i + 4]) ||
                    !hexdigit(p[*i + 5]))
                    return 0;
                *i += 6;
                continue;
            }
            if (!strchr("\"\\/bfnrt", e) || !e) return 0;
            *i += 2;
            continue;
        }
        (*i)++;
    }
    return 0;
}

static int json_number(const uint8_t *p, int64_t n, int64_t *i) {
    if (*i < n && p[*i] == '-') (*i)++;
    if (*i >= n) return 0;
    if (p[*i] == '0') (*i)++;
    else if (p[*i] >= '1' && p[*i] <= '9') { while (*i < n && p[*i] >= '0' && p[*i] <= '9') (*i)++; }
    else return 0;
    if (*i < n && p[*i] == '.') {
        (*i)++;
        int64_t s = *i;
        while (*i < n && p[*i] >= '0' && p[*i] <= '9') (*i)++;
        if (*i == s) return 0;
    }
    if (*i < n && (p[*i] == 'e' || p[*i] == 'E')) {
        (*i)++;
        if (*i < n && (p[*i] == '+' || p[*i] == '-')) (*i)++;
        int64_t s = *i;
        while (*i < n && p[*i] >= '0' && p[*i] <= '9') (*i)++;
        if (*i == s) return 0;
    }
    return 1;
}

static int json_value(const uint8_t *p, int64_t n, int64_t *i, int depth, event_t *top);

static int json_object(const uint8_t *p, int64_t n, int64_t *i, int depth, event_t *top) {
    (*i)++; /* { */
    ws(p, n, i);
    if (*i < n && p[*i] == '}') { (*i)++; return 1; }
    for (;;) {
        int64_t key_at = *i + 1;
        int escaped;
        if (!json_string(p, n, i, &escaped)) return 0;
        int64_t key_len = *i - 1 - key_at;
        if (top && escaped) return 0; /* a top-level key Python may read otherwise */
        ws(p, n, i);
        if (*i >= n || p[*i] != ':') return 0;
        (*i)++;
        ws(p, n, i);
        int64_t value_at = *i;
        if (!json_value(p, n, i, depth + 1, NULL)) return 0;
        if (top) {
            int64_t *at = NULL, *len = NULL;
            if (key_len == 4 && memcmp(p + key_at, "kind", 4) == 0) { at = &top->kind_at; len = &top->kind_len; }
            else if (key_len == 11 && memcmp(p + key_at, "sim_time_ns", 11) == 0) { at = &top->sim_at; len = &top->sim_len; }
            else if (key_len == 12 && memcmp(p + key_at, "wall_time_ns", 12) == 0) { at = &top->wall_at; len = &top->wall_len; }
            if (at) {
                if (*at >= 0) return 0; /* twice: Python takes the last */
                *at = value_at;
                *len = *i - value_at;
            }
        }
        ws(p, n, i);
        if (*i < n && p[*i] == ',') { (*i)++; ws(p, n, i); continue; }
        if (*i < n && p[*i] == '}') { (*i)++; return 1; }
        return 0;
    }
}

static int json_value(const uint8_t *p, int64_t n, int64_t *i, int depth, event_t *top) {
    if (depth > JSON_DEPTH || *i >= n) return 0;
    uint8_t c = p[*i];
    int escaped;
    if (c == '{') return json_object(p, n, i, depth, top);
    if (c == '[') {
        (*i)++;
        ws(p, n, i);
        if (*i < n && p[*i] == ']') { (*i)++; return 1; }
        for (;;) {
            if (!json_value(p, n, i, depth + 1, NULL)) return 0;
            ws(p, n, i);
            if (*i < n && p[*i] == ',') { (*i)++; ws(p, n, i); continue; }
            if (*i < n && p[*i] == ']') { (*i)++; return 1; }
            return 0;
        }
    }
    if (c == '"') return json_string(p, n, i, &escaped);
    if (c == 't') return lit(p, n, i, "true");
    if (c == 'f') return lit(p, n, i, "false");
    if (c == 'n') return lit(p, n, i, "null");
    return json_number(p, n, i);
}

/* A value that is a time as Python's careful path reads one (an int, 0 <= t < 2^62), written
 * as JSON writes it; 0 if not so. */
static int time_value(const uint8_t *p, int64_t at, int64_t len, uint64_t *t) {
    int64_t i = at;
    if (!canon_int(p, at + len, &i) || i != at + len) return 0;
    uint64_t v = 0;
    for (int64_t j = at; j < at + len; j++) v = v * 10 + (uint64_t)(p[j] - '0');
    if (v >= MAX_TIME) return 0;
    *t = v;
    return 1;
}

/* The fast path's int_field: the integer after the first `name` (\s*(-?\d+)\s*[,}]); 1 found
 * (a time in *t), 0 absent, -1 anything else (Python's). */
static int int_field(const uint8_t *p, int64_t n, const char *name, uint64_t *t) {
    const uint8_t *f = find(p, n, name);
    if (!f) return 0;
    int64_t i = (f - p) + (int64_t)strlen(name);
#define SPACE(c) ((c) == ' ' || (c) == '\t' || (c) == '\n' || (c) == '\r' || (c) == '\f' || (c) == '\v')
    while (i < n && SPACE(p[i])) i++;
    int neg = i < n && p[i] == '-';
    if (neg) i++;
    uint64_t v;
    if (!digits(p, n, &i, &v, MAX_DIGITS)) return -1;
    while (i < n && SPACE(p[i])) i++;
#undef SPACE
    if (i >= n || (p[i] != ',' && p[i] != '}')) return -1;
    if ((neg && v) || v >= MAX_TIME) return -1;
    *t = v;
    return 1;
}

static void span(batch_t *b, int64_t log_time) {
    b->frames++;
    if (b->frames == 1 || log_time < b->tmin) b->tmin = log_time;
    if (b->frames == 1 || log_time > b->tmax) b->tmax = log_time;
}

/* A sample written here whole: 0, or FB_CHUNK_FULL after it (the caller moves on first). */
static int plain_message(batch_t *b, int32_t cid, int64_t sim, int have_sim, uint64_t pub, const uint8_t *p,
                         int64_t n) {
    if (have_sim && sim > b->last_sim) b->last_sim = sim;
    int64_t log_time = b->by_sim ? b->origin + (have_sim ? sim : b->last_sim) : b->wall;
    span(b, log_time);
    return message(b, cid, (uint64_t)log_time, pub, p, n, NULL, 0) ? FB_CHUNK_FULL : 0;
}

/* 0 if data frames as pack_batch's bytes with ASCII keys (what fb_packed takes), else 1. */
int fb_check_packed(const uint8_t *data, int64_t len) {
    int64_t pos = 0;
    while (pos < len) {
        if (len - pos < 6) return 1;
        const uint8_t *s = data + pos;
        int64_t klen = s[0] | (s[1] << 8);
        int64_t plen = (int64_t)s[2] | ((int64_t)s[3] << 8) | ((int64_t)s[4] << 16) | ((int64_t)s[5] << 24);
        if (!klen || 6 + klen + plen > len - pos) return 1;
        for (int64_t j = 0; j < klen; j++) if (s[6 + j] >= 0x80) return 1;
        pos += 6 + klen + plen;
    }
    return 0;
}

int fb_packed(batch_t *b) {
    keys_t *keys = b->keys;
    /* a batch that does not frame, or has a key that is not ASCII, is Python's whole */
    if (b->pos == 0 && b->samples == 0 && fb_check_packed(b->packed, b->packed_len)) return FB_BAD_BATCH;
    while (b->pos < b->packed_len) {
        const uint8_t *s = b->packed + b->pos;
        int64_t left = b->packed_len - b->pos;
        if (left < 6) return FB_BAD_BATCH;
        int64_t klen = s[0] | (s[1] << 8);
        int64_t plen = (int64_t)s[2] | ((int64_t)s[3] << 8) | ((int64_t)s[4] << 16) | ((int64_t)s[5] << 24);
        if (!klen || 6 + klen + plen > left) return FB_BAD_BATCH;
        const uint8_t *key = s + 6, *p = key + klen;
        int64_t n = plen, next = b->pos + 6 + klen + plen;
        for (int64_t j = 0; j < klen; j++) if (key[j] >= 0x80) return FB_BAD_BATCH; /* Python decodes it */
        slot_t *ks = table_get(&keys->t, key, (int32_t)klen, (const uint8_t *)"", 0, TAG_KEY);
        if (!ks) return FB_NEW_KEY;
        int64_t id = ks->id;
        b->key_id = id;
        int32_t cls = keys->cls[id], cid = keys->cid[id];
        if (cls == FB_KEY_PYTHON) return FB_PYTHON;
        if (cls == FB_KEY_RECORD) {
            if (b->phase == 2) { /* its record is written, its scene message was behind a full chunk */
                if (!room(b, MESSAGE_HEADER + 32 + b->scene_rest_len)) return FB_OUT_FULL;
                b->phase = 0;
                b->pos = next;
                b->samples++;
                if (scene_message(b)) return FB_CHUNK_FULL;
                continue;
            }
            if (cid == 0) {
                if (b->phase) return -1;
                return FB_NEW_CHANNEL;
            }
            int code = record(b, cid, p, n, 1);
            if (code == FB_NOT_FRAME) return FB_PYTHON;
            if (code == RECORD_SCENE_NEXT) {
                keys->count[id]++;
                b->phase = 2;
                return FB_CHUNK_FULL;
            }
            if (code != 0 && code != RECORD_CHUNK_FULL && code != RECORD_COILS) return code;
            keys->count[id]++;
            b->item = b->pos;
            b->pos = next;
            b->samples++;
            if (code == RECORD_COILS) return FB_COILS;
            if (code == RECORD_CHUNK_FULL) return FB_CHUNK_FULL;
            continue;
        }
        if (cls == FB_KEY_FAST || cls == FB_KEY_EVENT) {
            uint64_t sim = 0, pub = (uint64_t)b->wall;
            int have_sim;
            if (n < 2 || p[0] != '{' || p[n - 1] != '}') return FB_PYTHON;
            if (cls == FB_KEY_FAST) {
                have_sim = int_field(p, n, "\"sim_time_ns\":", &sim);
                uint64_t w;
                int have_wall = int_field(p, n, "\"wall_time_ns\":", &w);
                if (have_sim < 0 || have_wall < 0) return FB_PYTHON;
                if (have_wall) pub = w;
            } else {
                event_t ev = {-1, 0, -1, 0, -1, 0};
                int64_t i = 0;
                if (!json_value(p, n, &i, 0, &ev) || i != n || ev.kind_at < 0) return FB_PYTHON;
                int64_t ka = ev.kind_at + 1;
                if (ev.kind_len < 2 || p[ev.kind_at] != '"' || !plain(p, ka, ev.kind_at + ev.kind_len - 1))
                    return FB_PYTHON;
                have_sim = ev.sim_at >= 0;
                if (have_sim && !time_value(p, ev.sim_at, ev.sim_len, &sim)) return FB_PYTHON;
                if (ev.wall_at >= 0 && !time_value(p, ev.wall_at, ev.wall_len, &pub)) return FB_PYTHON;
                if ((uint64_t)b->origin + sim >= (1ULL << 63)) return FB_PYTHON;
                if (cid == 0) return FB_NEW_CHANNEL;
                if (cid >= b->nseqs) return FB_GROW_SEQS;
                if (!room(b, n)) return FB_OUT_FULL;
                slot_t *k = table_get(b->kinds, p + ka, (int32_t)(ev.kind_len - 2), (const uint8_t *)"", 0, TAG_KIND);
                if (!k) k = table_put_tag(b->kinds, p + ka, (int32_t)(ev.kind_len - 2), (const uint8_t *)"", 0,
                                          (const uint8_t *)"", 0, TAG_KIND);
                if (!k) return -1;
                k->id++; /* its count (errors_by_kind) */
                b->events++;
            }
            if ((uint64_t)b->origin + sim >= (1ULL << 63)) return FB_PYTHON;
            if (cid == 0) return FB_NEW_CHANNEL;
            if (cid >= b->nseqs) return FB_GROW_SEQS;
            if (!room(b, n)) return FB_OUT_FULL;
            keys->count[id]++;
            b->pos = next;
            b->samples++;
            if (plain_message(b, cid, (int64_t)sim, have_sim, pub, p, n)) return FB_CHUNK_FULL;
            continue;
        }
        /* a frame */
        int64_t head_len, kind_at, kind_len;
        uint64_t sim, pub;
        if (!parse(p, n, &head_len, &sim, &pub, &kind_at, &kind_len) || sim >= MAX_TIME || pub >= MAX_TIME ||
            (uint64_t)b->origin + sim >= (1ULL << 63)) {
            if (b->phase) return -1;
            return FB_PYTHON;
        }
        int64_t log_time = b->by_sim ? b->origin + (int64_t)sim : b->wall;
        b->head_at = (p - b->packed);
        b->head_len = head_len;
        b->kind_at = (p - b->packed) + kind_at;
        b->kind_len = kind_len;
        b->log_time = log_time;
        b->item = b->pos;
        if (b->phase == 0) {
            if (cid == 0) return FB_NEW_CHANNEL;
            if (cid >= b->nseqs) return FB_GROW_SEQS;
            if (!room(b, n)) return FB_OUT_FULL;
            if ((int64_t)sim > b->last_sim) b->last_sim = (int64_t)sim;
            span(b, log_time);
            keys->count[id]++;
            if (kind_len == 5 && memcmp(p + kind_at, "noise", 5) == 0) keys->noise[id]++;
            b->phase = 1;
            b->no_log = 0;
            if (message(b, cid, (uint64_t)log_time, pub, p, n, NULL, 0)) return FB_CHUNK_FULL;
        }
        if (b->log_cid >= 0 && !b->no_log) {
            slot_t *r = table_get(b->rests, p, (int32_t)head_len, p + kind_at, (int32_t)kind_len, TAG_LOG);
            if (!r) r = compose(b, p, n, head_len, kind_at, kind_len);
            if (!r) return FB_REST_MISS;
            if (b->log_cid == 0) return FB_NEW_LOG_CHANNEL;
            if (b->log_cid >= b->nseqs) return FB_GROW_SEQS;
            uint8_t stamp[32];
            int sl = timestamp_field(stamp, (uint64_t)log_time);
            if (!room(b, sl + r->rest_len)) return FB_OUT_FULL;
            b->phase = 0;
            b->pos = next;
            b->samples++;
            if (message(b, b->log_cid, (uint64_t)log_time, (uint64_t)log_time, stamp, sl, r->rest, r->rest_len))
                return FB_CHUNK_FULL;
            continue;
        }
        b->phase = 0;
        b->pos = next;
        b->samples++;
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

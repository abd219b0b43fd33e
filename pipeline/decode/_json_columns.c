/*
 * Schema-specialised JSON object parser: payload spans of decompressed MCAP chunks ->
 * typed columns, without a Python object per message.
 *
 * Why: polars.read_ndjson costs ~2-2.5 CPU-s per million 440-byte radar reports and
 * needs the payloads copied into one newline-delimited buffer first (docs/ingest_speed.md).
 * This parser reads the payloads where they lie (in the decompressed chunks), knows the
 * wanted keys and their types in advance, and releases the GIL, so two threads parse two
 * halves of a group.
 *
 * It is strict and conservative: it accepts only what it can decode exactly and flags
 * every other row (status != 0) for the Python fallback (json_bulk.parse_json_payloads),
 * which gives the exact reject reasons. Flagged: invalid JSON, a value of the wrong JSON
 * type for its field (a fraction or exponent for an integer field, a string for a number,
 * ...), a string with an escape or a non-ASCII byte (UTF-8 is checked by the fallback), a
 * duplicate key, nesting deeper than 32, an integer out of int64, a number with more than
 * 19 significant digits, an exponent beyond +-999, or one whose double is subnormal,
 * infinite or zero by underflow, bytes after the object. Values of unknown keys are
 * skipped but checked the same way (a string with an escape or a non-ASCII byte, a
 * number the fallback would call non-finite or refuse: the row is flagged). A missing key
 * or a null value gives a null. Whitespace between tokens may include newlines (valid
 * JSON; the fallback accepts them too).
 *
 * Numbers: a decimal significand w (<= 19 digits, exact in uint64) and exponent q are
 * converted to the correctly rounded double by the Eisel-Lemire algorithm (D. Lemire,
 * "Number Parsing at a Gigabyte per Second", Softw. Pract. Exper. 51(8), 2021; the
 * 128-bit product is always sufficient for an exact 19-digit w: N. Mushtak, D. Lemire,
 * "Fast Number Parsing Without Fallback", Softw. Pract. Exper. 53(6), 2023). The tests
 * check the result against Python's float() bit for bit. Clinger's fast path (one exact
 * IEEE multiplication or division when w <= 2^53 and |q| <= 22) is not taken: a sensor's
 * 16- and 17-digit values fall on either side of 2^53 at random, and that branch
 * mispredicted about once per value (a 440-byte radar report, together with fast_decimal
 * and the branch-free sign: 4.9 -> 2.4 mispredictions, 13% fewer cycles in the best of 6
 * runs, 0.5% fewer instructions).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>
#include <string.h>

#include "_pow5_128.h"

enum { ST_OK = 0, ST_SYNTAX = 1, ST_TYPE = 2, ST_STRING = 3, ST_DUPLICATE = 4,
       ST_NUMBER = 5, ST_DEPTH = 6 };

#define MAX_FIELDS 64
#define MAX_DEPTH 32

typedef struct {
    int nfields;
    const char *key[MAX_FIELDS];
    Py_ssize_t key_len[MAX_FIELDS];
    char kind[MAX_FIELDS]; /* 'f' float64, 'i' int64, 's' string span, 'b' bool */
    char *out[MAX_FIELDS];
    uint8_t *valid;        /* nfields x n, field-major */
    uint8_t *status;       /* n */
    Py_ssize_t n;
} Spec;

static inline const uint8_t *skip_ws(const uint8_t *p, const uint8_t *e)
{
    /* every byte that is not blank is > ' ': one compare for the usual case */
    while (p < e && *p <= ' ' && (*p == ' ' || *p == '\n' || *p == '\r' || *p == '\t'))
        p++;
    return p;
}

/* -- numbers ------------------------------------------------------------------------- */

typedef struct {
    uint64_t w;   /* significand, at most 19 digits */
    int64_t q;    /* decimal exponent: value = w * 10^q */
    int neg;
    int is_int;   /* no fraction, no exponent */
    int exact;    /* no significant digit was dropped */
} Number;

/* Eight ASCII digits at once (SWAR; the fast_float library's parse_eight_digits). */
static inline uint64_t load8(const uint8_t *p)
{
    uint64_t v;
    memcpy(&v, p, 8);
    return v;
}

static inline uint64_t eight_digits_value(uint64_t v)
{
    const uint64_t mask = UINT64_C(0x000000FF000000FF);
    const uint64_t mul1 = UINT64_C(0x000F424000000064); /* 100 + (1000000 << 32) */
    const uint64_t mul2 = UINT64_C(0x0000271000000001); /* 1 + (10000 << 32) */
    v -= UINT64_C(0x3030303030303030);
    v = (v * 10) + (v >> 8);
    return (((v & mask) * mul1) + (((v >> 16) & mask) * mul2)) >> 32;
}

static inline uint32_t load4(const uint8_t *p)
{
    uint32_t v;
    memcpy(&v, p, 4);
    return v;
}

/* Number of leading ASCII digits in the 8 bytes v (first byte lowest), 0-8: a byte is a
 * digit when (byte ^ '0') < 10; bit 7 of each byte of m is set for a non-digit (no carry
 * crosses bytes: (x & 0x7F) + 0x76 <= 0xF5). */
static inline int leading_digits(uint64_t v)
{
    uint64_t x = v ^ UINT64_C(0x3030303030303030);
    uint64_t m = (((x & UINT64_C(0x7F7F7F7F7F7F7F7F)) + UINT64_C(0x7676767676767676)) | x) &
                 UINT64_C(0x8080808080808080);
    return m ? __builtin_ctzll(m) >> 3 : 8;
}

static const uint64_t POW10_U64[9] = {1, 10, 100, 1000, 10000, 100000, 1000000, 10000000,
                                      100000000};

/* Value of the first L (1-8) digits of v: shifted to the top and led by '0's, they are
 * an eight-digit number. */
static inline uint64_t first_digits_value(uint64_t v, int L)
{
    if (L == 8) return eight_digits_value(v);
    return eight_digits_value((v << (64 - 8 * L)) |
                              (UINT64_C(0x3030303030303030) >> (8 * L)));
}

/* The digit run at *pp into (w, sig), 8 bytes at a time while 8 bytes remain and the
 * significand stays within 19 digits; returns how many digits were taken (the caller's
 * byte loop does the rest: the end of the payload, a 20th digit). */
static inline __attribute__((always_inline)) int
take_digits(const uint8_t **pp, const uint8_t *e, uint64_t *w, int *sig)
{
    const uint8_t *p = *pp;
    int taken = 0;
    while (e - p >= 8) {
        uint64_t v = load8(p);
        int L = leading_digits(v);
        if (L == 0 || *sig + L > 19) break;
        *w = *w * POW10_U64[L] + first_digits_value(v, L);
        *sig += L;
        p += L;
        taken += L;
        if (L < 8) break;
    }
    *pp = p;
    return taken;
}

/* JSON number grammar: -?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][+-]?[0-9]+)?; NULL if none.
 * Locals, not n->..., in the loops: stores through n could alias the uint8_t input. */
static inline __attribute__((always_inline)) const uint8_t *
scan_number(const uint8_t *p, const uint8_t *e, Number *n)
{
    uint64_t w = 0;
    int64_t q = 0;
    int sig = 0, neg = 0, is_int = 1, exact = 1;
    if (p < e && *p == '-') { neg = 1; p++; }
    if (p >= e) return NULL;
    if (*p == '0') {
        p++;
    } else if (*p >= '1' && *p <= '9') {
        take_digits(&p, e, &w, &sig);
        for (; p < e && (unsigned)(*p - '0') < 10; p++) {
            if (sig < 19) { w = w * 10 + (uint64_t)(*p - '0'); sig++; }
            else { q++; exact = 0; }
        }
    } else {
        return NULL;
    }
    if (p < e && *p == '.') {
        const uint8_t *f0 = ++p;
        is_int = 0;
        if (w == 0)
            while (p < e && *p == '0') { q--; p++; } /* leading zeros: not significant */
        q -= take_digits(&p, e, &w, &sig);
        for (; p < e && (unsigned)(*p - '0') < 10; p++) {
            if (sig < 19) { w = w * 10 + (uint64_t)(*p - '0'); sig++; q--; }
            else { exact = 0; }
        }
        if (p == f0) return NULL;
    }
    if (p < e && (*p == 'e' || *p == 'E')) {
        int eneg = 0;
        int64_t ev = 0;
        const uint8_t *e0;
        is_int = 0;
        p++;
        if (p < e && (*p == '+' || *p == '-')) { eneg = (*p == '-'); p++; }
        e0 = p;
        for (; p < e && (unsigned)(*p - '0') < 10; p++)
            if (ev < 100000) ev = ev * 10 + (*p - '0');
        if (p == e0) return NULL;
        if (ev > 999) exact = 0; /* no double needs it; polars refuses very long ones */
        q += eneg ? -ev : ev;
    }
    n->w = w; n->q = q; n->neg = neg; n->is_int = is_int; n->exact = exact;
    return p;
}

/* Eisel-Lemire: w * 10^q correctly rounded, w != 0 exact. 0 when the result is
 * subnormal, underflows or overflows (left to the fallback). */
static inline __attribute__((always_inline)) int eisel_lemire(int64_t q, uint64_t w, double *out)
{
    const uint64_t *t;
    unsigned __int128 p1;
    uint64_t hi, lo, mantissa, bits;
    int lz, upperbit, shift;
    int64_t power2;
    if (q < POW5_SMALLEST || q > POW5_LARGEST) return 0;
    lz = __builtin_clzll(w);
    w <<= lz;
    t = &POW5_128[2 * (q - POW5_SMALLEST)];
    p1 = (unsigned __int128)w * t[0];
    hi = (uint64_t)(p1 >> 64);
    lo = (uint64_t)p1;
    if ((hi & 0x1FF) == 0x1FF) { /* 55 bits of precision wanted: look at the next word */
        uint64_t hi2 = (uint64_t)(((unsigned __int128)w * t[1]) >> 64);
        lo += hi2;
        if (hi2 > lo) hi++;
    }
    upperbit = (int)(hi >> 63);
    shift = upperbit + 9;
    mantissa = hi >> shift;
    power2 = ((((152170 + 65536) * q) >> 16) + 63) + upperbit - lz + 1023;
    if (power2 <= 0) return 0;
    if (lo <= 1 && q >= -4 && q <= 23 && (mantissa & 3) == 1 && (mantissa << shift) == hi)
        mantissa &= ~(uint64_t)1; /* exactly halfway: round to even */
    mantissa += mantissa & 1;
    mantissa >>= 1;
    if (mantissa >= (UINT64_C(2) << 52)) { mantissa = UINT64_C(1) << 52; power2++; }
    mantissa &= ~(UINT64_C(1) << 52);
    if (power2 >= 0x7FF) return 0;
    bits = mantissa | ((uint64_t)power2 << 52);
    memcpy(out, &bits, sizeof bits);
    return 1;
}

static inline __attribute__((always_inline)) int number_to_double(const Number *n, double *out)
{
    double d;
    if (!n->exact) return 0;
    if (n->w == 0) {
        d = 0.0;
    } else if (!eisel_lemire(n->q, n->w, &d)) {
        return 0;
    }
    {   /* the sign bit without a branch: x and y are negative about half the time */
        uint64_t bits;
        memcpy(&bits, &d, sizeof bits);
        bits |= (uint64_t)(n->neg != 0) << 63;
        memcpy(out, &bits, sizeof bits);
    }
    return 1;
}

/* -- values -------------------------------------------------------------------------- */

/* A string starting at p (after the opening quote); *plain = no escape, all ASCII. */
static const uint8_t *scan_string(const uint8_t *p, const uint8_t *e, int *plain)
{
    const uint64_t ones = UINT64_C(0x0101010101010101), high = UINT64_C(0x8080808080808080);
    *plain = 1;
    /* 8 bytes at a time to the first quote, backslash, control byte or non-ASCII byte
     * (bit 7 of each flagged byte; the lowest one is exact: a borrow only runs past a
     * byte that is flagged itself); the byte loop takes it from there */
    while (e - p >= 8) {
        uint64_t v = load8(p), quote = v ^ (ones * '"'), slash = v ^ (ones * '\\');
        uint64_t m = (((quote - ones) & ~quote) | ((slash - ones) & ~slash) |
                      ((v - ones * 0x20) & ~v) | v) & high;
        if (m) { p += __builtin_ctzll(m) >> 3; break; }
        p += 8;
    }
    while (p < e) {
        uint8_t c = *p;
        if (c == '"') return p;
        if (c < 0x20) return NULL;
        if (c == '\\') {
            *plain = 0;
            if (++p >= e) return NULL;
        } else if (c >= 0x80) {
            *plain = 0;
        }
        p++;
    }
    return NULL;
}

static const uint8_t *match_literal(const uint8_t *p, const uint8_t *e, const char *lit, size_t len)
{
    return ((size_t)(e - p) >= len && memcmp(p, lit, len) == 0) ? p + len : NULL;
}

/* Skip any JSON value; NULL (and *st) on error. */
static const uint8_t *skip_value(const uint8_t *p, const uint8_t *e, int depth, int *st)
{
    Number num;
    int plain;
    if (p >= e) { *st = ST_SYNTAX; return NULL; }
    switch (*p) {
    case '"':
        p = scan_string(p + 1, e, &plain);
        if (!p) { *st = ST_SYNTAX; return NULL; }
        if (!plain) { *st = ST_STRING; return NULL; } /* escapes and UTF-8: fallback */
        return p + 1;
    case 't': p = match_literal(p, e, "true", 4); break;
    case 'f': p = match_literal(p, e, "false", 5); break;
    case 'n': p = match_literal(p, e, "null", 4); break;
    case '{':
    case '[': {
        uint8_t close = *p == '{' ? '}' : ']';
        int object = *p == '{';
        if (depth >= MAX_DEPTH) { *st = ST_DEPTH; return NULL; }
        p = skip_ws(p + 1, e);
        if (p < e && *p == close) return p + 1;
        for (;;) {
            if (object) {
                if (p >= e || *p != '"') { *st = ST_SYNTAX; return NULL; }
                p = scan_string(p + 1, e, &plain);
                if (!p) { *st = ST_SYNTAX; return NULL; }
                if (!plain) { *st = ST_STRING; return NULL; }
                p = skip_ws(p + 1, e);
                if (p >= e || *p != ':') { *st = ST_SYNTAX; return NULL; }
                p = skip_ws(p + 1, e);
            }
            p = skip_value(p, e, depth + 1, st);
            if (!p) return NULL;
            p = skip_ws(p, e);
            if (p < e && *p == ',') { p = skip_ws(p + 1, e); continue; }
            if (p < e && *p == close) return p + 1;
            *st = ST_SYNTAX;
            return NULL;
        }
    }
    default: {
        double ignored;
        p = scan_number(p, e, &num);
        if (p && !number_to_double(&num, &ignored)) { *st = ST_NUMBER; return NULL; }
    }
    }
    if (!p) *st = ST_SYNTAX;
    return p;
}

/* The usual float of an encoder, [-]I.F with 1-7 integer digits (no leading zero unless
 * alone), 1-15 fraction digits, at most 19 digits in all and no exponent, into (w, q): the
 * end of the number, or NULL for any other form (scan_number then reads it). Straight-line
 * SWAR over three 8-byte words: the generic digit loops mispredict on the varying digit
 * counts. Reads 25 bytes from p (the caller checks that they lie in the payload). */
static inline __attribute__((always_inline)) const uint8_t *
fast_decimal(const uint8_t *p, Number *n)
{
    uint64_t v0, v1, v2, w;
    int L, F1, F2;
    const uint8_t *f;
    n->neg = *p == '-';
    p += n->neg;
    v0 = load8(p);
    L = leading_digits(v0);
    if ((unsigned)(L - 1) >= 7u || p[L] != '.' || (p[0] == '0' && L > 1)) return NULL;
    f = p + L + 1;
    v1 = load8(f);
    F1 = leading_digits(v1);
    if (F1 == 0) return NULL;
    w = first_digits_value(v0, L);
    if (F1 < 8) {
        w = w * POW10_U64[F1] + first_digits_value(v1, F1);
        n->q = -F1;
        f += F1;
    } else {
        v2 = load8(f + 8);
        F2 = leading_digits(v2);
        if (F2 == 8 || L + 8 + F2 > 19) return NULL;
        w = w * 100000000u + eight_digits_value(v1);
        if (F2) w = w * POW10_U64[F2] + first_digits_value(v2, F2);
        n->q = -(8 + F2);
        f += 8 + F2;
    }
    if ((*f | 0x20) == 'e') return NULL;
    n->w = w;
    n->is_int = 0;
    n->exact = 1;
    return f;
}

/* Read the value of field f for row r into its column; NULL (and *st) on error. */
static inline __attribute__((always_inline)) const uint8_t *
read_field(const Spec *s, int f, Py_ssize_t r, const uint8_t *base, const uint8_t *p,
           const uint8_t *e, int *st)
{
    Number num;
    const uint8_t *q;
    int plain;
    char kind = s->kind[f];
    if (p < e && *p == 'n') {
        q = match_literal(p, e, "null", 4);
        if (!q) *st = ST_SYNTAX;
        return q; /* valid stays 0 */
    }
    if (kind == 's') {
        if (p >= e || *p != '"') { *st = (p < e) ? ST_TYPE : ST_SYNTAX; return NULL; }
        q = scan_string(p + 1, e, &plain);
        if (!q) { *st = ST_SYNTAX; return NULL; }
        if (!plain) { *st = ST_STRING; return NULL; }
        ((int64_t *)s->out[f])[2 * r] = (p + 1) - base;
        ((int64_t *)s->out[f])[2 * r + 1] = q - base;
        s->valid[(Py_ssize_t)f * s->n + r] = 1;
        return q + 1;
    }
    if (kind == 'b') {
        uint8_t v;
        if ((q = match_literal(p, e, "true", 4)) != NULL) v = 1;
        else if ((q = match_literal(p, e, "false", 5)) != NULL) v = 0;
        else { *st = ST_TYPE; return NULL; }
        ((uint8_t *)s->out[f])[r] = v;
        s->valid[(Py_ssize_t)f * s->n + r] = 1;
        return q;
    }
    /* a number */
    if (p >= e || !(*p == '-' || (*p >= '0' && *p <= '9'))) { *st = ST_TYPE; return NULL; }
    q = kind == 'f' && e - p >= 25 ? fast_decimal(p, &num) : NULL;
    if (!q) q = scan_number(p, e, &num);
    if (!q) { *st = ST_SYNTAX; return NULL; }
    if (kind == 'i') {
        int64_t v;
        if (!num.is_int) { *st = ST_TYPE; return NULL; }
        if (!num.exact || num.q != 0) { *st = ST_NUMBER; return NULL; }
        if (num.neg) {
            if (num.w > (UINT64_C(1) << 63)) { *st = ST_NUMBER; return NULL; }
            v = (int64_t)(UINT64_C(0) - num.w);
        } else {
            if (num.w > (uint64_t)INT64_MAX) { *st = ST_NUMBER; return NULL; }
            v = (int64_t)num.w;
        }
        ((int64_t *)s->out[f])[r] = v;
    } else {
        double d;
        if (!number_to_double(&num, &d)) { *st = ST_NUMBER; return NULL; }
        if (num.is_int && num.w == 0) d = 0.0; /* "-0" is the integer 0, as in json.loads */
        ((double *)s->out[f])[r] = d;
    }
    s->valid[(Py_ssize_t)f * s->n + r] = 1;
    return q;
}

/* memcmp(a, b, len) == 0 for short keys, without a library call: 8-byte words, the last
 * one overlapping the previous (no byte outside [a, a + len) or [b, b + len) is read). */
static inline int same_bytes(const uint8_t *a, const char *b, Py_ssize_t len)
{
    const uint8_t *bb = (const uint8_t *)b;
    Py_ssize_t i = 0;
    if (len >= 8) {
        for (; i + 8 <= len; i += 8)
            if (load8(a + i) != load8(bb + i)) return 0;
        return i == len || load8(a + len - 8) == load8(bb + len - 8);
    }
    if (len >= 4)
        return load4(a) == load4(bb) && load4(a + len - 4) == load4(bb + len - 4);
    for (; i < len; i++)
        if (a[i] != bb[i]) return 0;
    return 1;
}

/* The wanted field named by key [k, k + len), or -1 (a key out of the expected order). */
static inline int find_key(const Spec *s, const uint8_t *k, Py_ssize_t len)
{
    int i;
    for (i = 0; i < s->nfields; i++)
        if (s->key_len[i] == len && same_bytes(k, s->key[i], len)) return i;
    return -1;
}

/* -- the shape of the rows ------------------------------------------------------------
 *
 * Archived reports of one channel are written by one encoder: the same keys in the same
 * order, the same punctuation and blanks. A row's *shape* is what lies between its values:
 * literal[0] value[0] literal[1] value[1] ... value[n-1] literal[n], where literal[0] is
 * the opening brace and the first key with its colon (and any blanks), literal[k] the
 * comma and the next key, literal[n] the closing brace. A row that matches the shape of
 * the previous good row byte for byte, literal by literal, is an object with exactly
 * those keys (so no duplicate, no escaped key), and its values are read by the same
 * read_field/skip_value as in parse_object: one 8-byte-word compare per field replaces
 * the blank skipping, the quote, key, colon and comma checks and the key lookup. A row
 * that does not match (another shape, a bad value, any error) is parsed again from its
 * start by parse_object, which gives its status and records its shape for the next rows.
 *
 * Each value slot also remembers the last value it read, as bytes (up to MEMO_BYTES) and
 * as the result: a sensor's reports repeat many values (a site's sigmas, scan period,
 * status), and the same bytes give the same result. Where a longer value starts with the
 * remembered bytes (a number with more digits), the next literal cannot match: it starts
 * with the byte that ended the value in the recorded row (a comma, brace or blank). A slot
 * that misses MEMO_TRIES times in a row (a position, a time) stops remembering until the
 * shape is recorded again.
 */

#define MAX_SLOTS 96  /* values per shape (wanted fields and skipped ones) */
#define MAX_LITERAL 64
#define MEMO_BYTES 24
#define MEMO_TRIES 8

typedef struct {
    uint8_t token[MEMO_BYTES];
    int len;     /* 0: nothing remembered */
    int misses;  /* values read since the last match */
    int null;    /* a null in a wanted field: nothing to store */
    uint64_t value; /* the wanted field's 8 (float/int) or 1 (bool) bytes */
} Memo;

typedef struct {
    int ok;                                    /* a shape was recorded */
    int nslots;
    signed char field[MAX_SLOTS];              /* wanted field of value k, -1: skipped */
    Py_ssize_t literal_len[MAX_SLOTS + 1];
    uint8_t literal[MAX_SLOTS + 1][MAX_LITERAL];
    Memo memo[MAX_SLOTS];
} Shape;

/* Record literal[k] = [from, to) of the shape being recorded; too long: no shape. */
static inline void record_literal(Shape *sh, int k, const uint8_t *from, const uint8_t *to)
{
    if (k > MAX_SLOTS || to - from > MAX_LITERAL) { sh->ok = 0; return; }
    sh->literal_len[k] = to - from;
    memcpy(sh->literal[k], from, (size_t)(to - from));
}

/* One payload [p, e) of row r; base: start of its chunk (spans are chunk offsets).
 * Records the row's shape in *rec (rec->ok = 0 when the row is not OK or too long). */
static int parse_object(const Spec *s, Py_ssize_t r, const uint8_t *base, const uint8_t *p,
                        const uint8_t *e, Shape *rec)
{
    uint64_t seen = 0;
    int hint = 0, st = ST_OK, plain, k = 0;
    const uint8_t *lit = p;
    rec->ok = 0;
    p = skip_ws(p, e);
    if (p >= e || *p != '{') return ST_SYNTAX;
    p = skip_ws(p + 1, e);
    rec->ok = 1;
    if (p < e && *p == '}') { p++; goto end; }
    for (;;) {
        const uint8_t *k0, *k1;
        int f;
        if (p >= e || *p != '"') return ST_SYNTAX;
        k0 = p + 1;
        if (hint < s->nfields && e - k0 > s->key_len[hint] && k0[s->key_len[hint]] == '"' &&
            same_bytes(k0, s->key[hint], s->key_len[hint])) {
            /* the expected next key, byte for byte (wanted keys hold no quote/escape) */
            k1 = k0 + s->key_len[hint];
            f = hint;
        } else {
            k1 = scan_string(k0, e, &plain);
            if (!k1) return ST_SYNTAX;
            f = plain ? find_key(s, k0, k1 - k0) : -2;
        }
        p = skip_ws(k1 + 1, e);
        if (p >= e || *p != ':') return ST_SYNTAX;
        p = skip_ws(p + 1, e);
        if (f == -2) return ST_STRING; /* an escaped key might spell a wanted one */
        record_literal(rec, k, lit, p);
        if (k < MAX_SLOTS) { /* slot k: its field, nothing remembered yet */
            rec->field[k] = (signed char)(f < 0 ? -1 : f);
            rec->memo[k].len = rec->memo[k].misses = 0;
        }
        k++;
        if (f < 0) {
            p = skip_value(p, e, 1, &st);
        } else {
            if (seen & (UINT64_C(1) << f)) return ST_DUPLICATE;
            seen |= UINT64_C(1) << f;
            hint = f + 1;
            p = read_field(s, f, r, base, p, e, &st);
        }
        if (!p) return st;
        lit = p;
        p = skip_ws(p, e);
        if (p < e && *p == ',') { p = skip_ws(p + 1, e); continue; }
        if (p < e && *p == '}') { p++; break; }
        return ST_SYNTAX;
    }
end:
    p = skip_ws(p, e);
    if (p != e) return ST_SYNTAX;
    record_literal(rec, k, lit, e);
    rec->nslots = k;
    return ST_OK;
}

/* The value [v, q) of slot k just read (field f of row r, -1: skipped; the payload ends
 * at e), remembered when short enough and not a wanted string (its output is a span of
 * this row). */
static inline void remember(const Spec *s, Memo *m, int f, Py_ssize_t r, const uint8_t *v,
                            const uint8_t *q, const uint8_t *e)
{
    char kind = f >= 0 ? s->kind[f] : 0;
    m->len = 0;
    if (q - v > MEMO_BYTES || kind == 's') return;
    m->null = f >= 0 && *v == 'n';
    if (f >= 0 && !m->null) {
        if (kind == 'b') m->value = ((uint8_t *)s->out[f])[r];
        else memcpy(&m->value, s->out[f] + 8 * r, 8);
    }
    if (e - v >= MEMO_BYTES) /* a fixed-size copy (the bytes after the value: not compared) */
        memcpy(m->token, v, MEMO_BYTES);
    else
        memcpy(m->token, v, (size_t)(q - v));
    m->len = (int)(q - v);
}

/* Row r read along shape sh; ST_OK, or -1 when it does not match (or any error). */
static inline int parse_shaped(const Spec *s, Shape *sh, Py_ssize_t r, const uint8_t *base,
                               const uint8_t *p, const uint8_t *e)
{
    int k, st = ST_OK;
    Py_ssize_t len;
    for (k = 0; k < sh->nslots; k++) {
        int f = sh->field[k];
        Memo *m = &sh->memo[k];
        const uint8_t *v;
        len = sh->literal_len[k];
        if (e - p < len || !same_bytes(p, (const char *)sh->literal[k], len)) return -1;
        p += len;
        if (m->len && e - p >= m->len && same_bytes(p, (const char *)m->token, m->len)) {
            if (f >= 0 && !m->null) {
                if (s->kind[f] == 'b') ((uint8_t *)s->out[f])[r] = (uint8_t)m->value;
                else memcpy(s->out[f] + 8 * r, &m->value, 8);
                s->valid[(Py_ssize_t)f * s->n + r] = 1;
            }
            p += m->len;
            m->misses = 0;
            continue;
        }
        v = p;
        p = f >= 0 ? read_field(s, f, r, base, p, e, &st) : skip_value(p, e, 1, &st);
        if (!p) return -1;
        if (m->misses < MEMO_TRIES) {
            m->misses++;
            remember(s, m, f, r, v, p, e);
        } else {
            m->len = 0;
        }
    }
    len = sh->literal_len[sh->nslots];
    return e - p == len && same_bytes(p, (const char *)sh->literal[sh->nslots], len) ? ST_OK : -1;
}

/* -- Python glue --------------------------------------------------------------------- */

typedef struct {
    Py_ssize_t count;
    Py_buffer *views;
} Buffers;

/* Rows [row0, row1): along the shape of the previous good row while they match it. */
static Py_ssize_t parse_rows(const Spec *s, const Buffers *cb, const int64_t *ck,
                             const int64_t *st, const int64_t *en, Py_ssize_t row0,
                             Py_ssize_t row1)
{
    Shape shapes[2];
    Shape *shape = &shapes[0], *rec = &shapes[1], *tmp;
    Py_ssize_t i, flagged = 0;
    int f;
    shape->ok = 0;
    for (i = row0; i < row1; i++) {
        const uint8_t *base = cb->views[ck[i]].buf;
        int code = shape->ok ? parse_shaped(s, shape, i, base, base + st[i], base + en[i]) : -1;
        if (code < 0) {
            if (shape->ok) /* the failed attempt may have set some */
                for (f = 0; f < s->nfields; f++) s->valid[(Py_ssize_t)f * s->n + i] = 0;
            code = parse_object(s, i, base, base + st[i], base + en[i], rec);
            if (code == ST_OK && rec->ok) { tmp = shape; shape = rec; rec = tmp; }
        }
        s->status[i] = (uint8_t)code;
        flagged += code != ST_OK;
    }
    return flagged;
}

static void release(Buffers *b)
{
    Py_ssize_t i;
    for (i = 0; i < b->count; i++) PyBuffer_Release(&b->views[i]);
    PyMem_Free(b->views);
    b->views = NULL;
    b->count = 0;
}

static int acquire(PyObject *seq, int flags, Buffers *b)
{
    PyObject *fast = PySequence_Fast(seq, "expected a sequence of buffers");
    Py_ssize_t i, n;
    if (!fast) return -1;
    n = PySequence_Fast_GET_SIZE(fast);
    b->count = 0;
    b->views = PyMem_Calloc(n > 0 ? n : 1, sizeof(Py_buffer));
    if (!b->views) { Py_DECREF(fast); PyErr_NoMemory(); return -1; }
    for (i = 0; i < n; i++) {
        if (PyObject_GetBuffer(PySequence_Fast_GET_ITEM(fast, i), &b->views[i], flags) < 0) {
            Py_DECREF(fast);
            release(b);
            return -1;
        }
        b->count++;
    }
    Py_DECREF(fast);
    return 0;
}

static int get_array(PyObject *obj, Py_buffer *view, Py_ssize_t itemsize, Py_ssize_t n,
                     int writable, const char *what)
{
    if (PyObject_GetBuffer(obj, view, writable ? PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS
                                               : PyBUF_C_CONTIGUOUS) < 0)
        return -1;
    if (view->len < itemsize * n) {
        PyBuffer_Release(view);
        PyErr_Format(PyExc_ValueError, "%s: buffer of %zd bytes, need %zd", what, view->len,
                     itemsize * n);
        return -1;
    }
    return 0;
}

PyDoc_STRVAR(parse_doc,
"parse_objects(chunks, chunk, start, end, keys, kinds, outputs, valid, status, row0, row1)\n"
"\n"
"Parse the JSON-object payloads chunks[chunk[r]][start[r]:end[r]] for rows r in\n"
"[row0, row1) into the columns ``outputs`` (one per key; kinds: 'f' float64[n],\n"
"'i' int64[n], 's' int64[2n] span (start, end) in the chunk, 'b' uint8[n]).\n"
"``valid``: uint8[len(keys) * n], 1 where field k of row r has a value (field-major);\n"
"``status``: uint8[n], 0 for a row decoded exactly, else why the row is left to the\n"
"fallback (1 syntax, 2 type, 3 string, 4 duplicate, 5 number, 6 depth). Returns the\n"
"number of flagged rows. The GIL is released while parsing.");

static PyObject *parse_objects(PyObject *self, PyObject *args)
{
    PyObject *chunks, *o_chunk, *o_start, *o_end, *keys, *outputs, *o_valid, *o_status;
    const char *kinds;
    Py_ssize_t nkinds, row0, row1, n, i, flagged = 0;
    Buffers cb = {0, NULL}, kb = {0, NULL}, ob = {0, NULL};
    Py_buffer vchunk, vstart, vend, vvalid, vstatus;
    int got = 0;
    Spec s;
    (void)self;
    if (!PyArg_ParseTuple(args, "OOOOOs#OOOnn", &chunks, &o_chunk, &o_start, &o_end, &keys,
                          &kinds, &nkinds, &outputs, &o_valid, &o_status, &row0, &row1))
        return NULL;
    if (nkinds > MAX_FIELDS) {
        PyErr_Format(PyExc_ValueError, "at most %d fields", MAX_FIELDS);
        return NULL;
    }
    if (get_array(o_status, &vstatus, 1, 0, 1, "status") < 0) return NULL;
    n = vstatus.len;
    if (row0 < 0 || row1 > n || row0 > row1) {
        PyBuffer_Release(&vstatus);
        PyErr_SetString(PyExc_ValueError, "rows out of range");
        return NULL;
    }
    if (get_array(o_chunk, &vchunk, 8, n, 0, "chunk") < 0) goto fail0;
    got = 1;
    if (get_array(o_start, &vstart, 8, n, 0, "start") < 0) goto fail;
    got = 2;
    if (get_array(o_end, &vend, 8, n, 0, "end") < 0) goto fail;
    got = 3;
    if (get_array(o_valid, &vvalid, 1, nkinds * n, 1, "valid") < 0) goto fail;
    got = 4;
    if (acquire(chunks, PyBUF_SIMPLE, &cb) < 0) goto fail;
    if (acquire(keys, PyBUF_SIMPLE, &kb) < 0) goto fail;
    if (acquire(outputs, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS, &ob) < 0) goto fail;
    if (kb.count != nkinds || ob.count != nkinds) {
        PyErr_SetString(PyExc_ValueError, "keys, kinds and outputs differ in length");
        goto fail;
    }
    s.nfields = (int)nkinds;
    s.n = n;
    s.valid = vvalid.buf;
    s.status = vstatus.buf;
    for (i = 0; i < nkinds; i++) {
        Py_ssize_t need;
        s.key[i] = kb.views[i].buf;
        s.key_len[i] = kb.views[i].len;
        s.kind[i] = kinds[i];
        s.out[i] = ob.views[i].buf;
        need = kinds[i] == 'f' || kinds[i] == 'i' ? 8 * n
             : kinds[i] == 's' ? 16 * n
             : kinds[i] == 'b' ? n : -1;
        if (need < 0 || ob.views[i].len < need) {
            PyErr_Format(PyExc_ValueError, "field %zd: bad kind or output too small", i);
            goto fail;
        }
    }
    {
        const int64_t *ck = vchunk.buf, *st = vstart.buf, *en = vend.buf;
        int bad_span = 0;
        for (i = row0; i < row1; i++) {
            if (ck[i] < 0 || ck[i] >= cb.count || st[i] < 0 || en[i] < st[i] ||
                en[i] > cb.views[ck[i]].len) {
                bad_span = 1;
                break;
            }
        }
        if (bad_span) {
            PyErr_SetString(PyExc_ValueError, "a payload span lies outside its chunk");
            goto fail;
        }
        Py_BEGIN_ALLOW_THREADS
        memset(s.status + row0, 0, (size_t)(row1 - row0));
        for (i = 0; i < nkinds; i++) memset(s.valid + i * n + row0, 0, (size_t)(row1 - row0));
        flagged = parse_rows(&s, &cb, ck, st, en, row0, row1);
        Py_END_ALLOW_THREADS
    }
    release(&cb);
    release(&kb);
    release(&ob);
    PyBuffer_Release(&vvalid);
    PyBuffer_Release(&vend);
    PyBuffer_Release(&vstart);
    PyBuffer_Release(&vchunk);
    PyBuffer_Release(&vstatus);
    return PyLong_FromSsize_t(flagged);
fail:
    release(&cb);
    release(&kb);
    release(&ob);
    if (got >= 4) PyBuffer_Release(&vvalid);
    if (got >= 3) PyBuffer_Release(&vend);
    if (got >= 2) PyBuffer_Release(&vstart);
    if (got >= 1) PyBuffer_Release(&vchunk);
fail0:
    PyBuffer_Release(&vstatus);
    return NULL;
}

PyDoc_STRVAR(gather_doc,
"gather_spans(chunks, chunk, spans) -> (offsets, data)\n"
"\n"
"Concatenate chunks[chunk[r]][spans[2r]:spans[2r+1]] for every row r (int64 arrays;\n"
"an empty span gives an empty string): ``offsets`` int32[n+1] and ``data`` as bytes,\n"
"the two buffers of an Arrow string array.");

static PyObject *gather_spans(PyObject *self, PyObject *args)
{
    PyObject *chunks, *o_chunk, *o_spans, *offsets = NULL, *data = NULL;
    Buffers cb = {0, NULL};
    Py_buffer vchunk, vspans;
    Py_ssize_t n, i, total = 0;
    (void)self;
    if (!PyArg_ParseTuple(args, "OOO", &chunks, &o_chunk, &o_spans)) return NULL;
    if (get_array(o_chunk, &vchunk, 8, 0, 0, "chunk") < 0) return NULL;
    n = vchunk.len / 8;
    if (get_array(o_spans, &vspans, 16, n, 0, "spans") < 0) {
        PyBuffer_Release(&vchunk);
        return NULL;
    }
    if (acquire(chunks, PyBUF_SIMPLE, &cb) < 0) goto done;
    {
        const int64_t *ck = vchunk.buf, *sp = vspans.buf;
        for (i = 0; i < n; i++) {
            if (ck[i] < 0 || ck[i] >= cb.count || sp[2 * i] < 0 || sp[2 * i + 1] < sp[2 * i] ||
                sp[2 * i + 1] > cb.views[ck[i]].len) {
                PyErr_SetString(PyExc_ValueError, "a span lies outside its chunk");
                goto done;
            }
            total += sp[2 * i + 1] - sp[2 * i];
        }
        if (total > INT32_MAX) {
            PyErr_SetString(PyExc_OverflowError, "more than 2 GiB of strings");
            goto done;
        }
        offsets = PyBytes_FromStringAndSize(NULL, 4 * (n + 1));
        data = PyBytes_FromStringAndSize(NULL, total);
        if (!offsets || !data) goto done;
        {
            int32_t *off = (int32_t *)PyBytes_AS_STRING(offsets);
            char *out = PyBytes_AS_STRING(data);
            int32_t pos = 0;
            off[0] = 0;
            for (i = 0; i < n; i++) {
                int32_t len = (int32_t)(sp[2 * i + 1] - sp[2 * i]);
                memcpy(out + pos, (const char *)cb.views[ck[i]].buf + sp[2 * i], (size_t)len);
                pos += len;
                off[i + 1] = pos;
            }
        }
    }
done:
    release(&cb);
    PyBuffer_Release(&vspans);
    PyBuffer_Release(&vchunk);
    if (PyErr_Occurred()) {
        Py_XDECREF(offsets);
        Py_XDECREF(data);
        return NULL;
    }
    return Py_BuildValue("(NN)", offsets, data);
}

PyDoc_STRVAR(to_double_doc,
"to_double(token: bytes) -> float | None\n"
"\n"
"The double of one JSON number token as the parser converts it; None when the parser\n"
"would leave it to the fallback (for tests).");

static PyObject *to_double(PyObject *self, PyObject *arg)
{
    Py_buffer v;
    Number num = {0, 0, 0, 0, 0};
    const uint8_t *p, *e;
    double d;
    int ok;
    (void)self;
    if (PyObject_GetBuffer(arg, &v, PyBUF_SIMPLE) < 0) return NULL;
    p = v.buf;
    e = p + v.len;
    p = scan_number(p, e, &num);
    ok = p == e && number_to_double(&num, &d);
    PyBuffer_Release(&v);
    if (!ok) Py_RETURN_NONE;
    return PyFloat_FromDouble(d);
}

static PyMethodDef methods[] = {
    {"parse_objects", parse_objects, METH_VARARGS, parse_doc},
    {"gather_spans", gather_spans, METH_VARARGS, gather_doc},
    {"to_double", to_double, METH_O, to_double_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_json_columns",
    "Schema-specialised JSON object parser (see _json_columns.c).", -1, methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__json_columns(void)
{
    return PyModule_Create(&module);
}

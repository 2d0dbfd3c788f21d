/* protocol.c - see protocol.h and PROTOCOL.md */
#include <string.h>
#include "protocol.h"

static const char *const err_text[] = {
    "OK", "BADCS", "SYNTAX", "UNKNOWN", "LIMIT",
    "NOTHOMED", "BUSY", "TRUNC", "BADARG",
};

const char *proto_err_text(uint8_t code)
{
    if (code < sizeof(err_text) / sizeof(err_text[0]))
        return err_text[code];
    return "?";
}

void proto_rx_init(line_rx_t *lr)
{
    lr->len = 0;
    lr->active = 0;
}

static int8_t hexval(char c)
{
    if (c >= '0' && c <= '9') return (int8_t)(c - '0');
    if (c >= 'A' && c <= 'F') return (int8_t)(c - 'A' + 10);
    if (c >= 'a' && c <= 'f') return (int8_t)(c - 'a' + 10);
    return -1;
}

/* best-effort sequence number of a (possibly broken) frame body */
static uint16_t peek_seq(const char *s, uint8_t n)
{
    uint32_t v = 0;
    uint8_t i = 0;
    while (i < n && i < 5 && s[i] >= '0' && s[i] <= '9') {
        v = v * 10u + (uint32_t)(s[i] - '0');
        i++;
    }
    if (i == 0 || i >= n || s[i] != ',' || v > 65535u)
        return 0;
    return (uint16_t)v;
}

/* parse "[-]digits" of at most 9 digits in s[*pos..end) */
static int8_t parse_int(const char *s, uint8_t *pos, uint8_t end, int32_t *out)
{
    uint8_t i = *pos, neg = 0, nd = 0;
    int32_t v = 0;
    if (i < end && s[i] == '-') { neg = 1; i++; }
    while (i < end && s[i] >= '0' && s[i] <= '9') {
        if (++nd > 9) return -1;
        v = v * 10 + (s[i] - '0');
        i++;
    }
    if (nd == 0) return -1;
    *out = neg ? -v : v;
    *pos = i;
    return 0;
}

static int8_t parse_body(const char *s, uint8_t n, frame_t *f)
{
    /* s[0..n) is the text between '$' and '*' */
    uint8_t i = 0;
    int32_t v;
    if (parse_int(s, &i, n, &v) < 0 || v < 0 || v > 65535 || s[0] == '-')
        return -E_SYNTAX;
    f->seq = (uint16_t)v;
    if (i >= n || s[i] != ',')
        return -E_SYNTAX;
    i++;
    uint8_t k = 0;
    while (i < n && s[i] != ',') {
        char c = s[i];
        if (!((c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9')) || k >= PROTO_CMD_MAX)
            return -E_SYNTAX;
        f->cmd[k++] = c;
        i++;
    }
    f->cmd[k] = 0;
    if (k == 0)
        return -E_SYNTAX;
    f->nargs = 0;
    while (i < n) {                 /* s[i] == ',' */
        i++;
        if (f->nargs >= PROTO_MAX_ARGS)
            return -E_ARG;
        if (parse_int(s, &i, n, &f->args[f->nargs]) < 0)
            return -E_SYNTAX;
        f->nargs++;
        if (i < n && s[i] != ',')
            return -E_SYNTAX;
    }
    return 1;
}

static int8_t finish_line(line_rx_t *lr, frame_t *f)
{
    const char *s = lr->buf;
    uint8_t n = lr->len;
    f->seq = 0;
    f->nargs = 0;
    f->cmd[0] = 0;
    /* must end in "*HH" */
    if (n < 3 || s[n - 3] != '*') {
        f->seq = peek_seq(s, n);
        return -E_SYNTAX;
    }
    int8_t hi = hexval(s[n - 2]), lo = hexval(s[n - 1]);
    uint8_t body = (uint8_t)(n - 3);
    if (hi < 0 || lo < 0) {
        f->seq = peek_seq(s, body);
        return -E_SYNTAX;
    }
    uint8_t cs = 0;
    for (uint8_t i = 0; i < body; i++)
        cs ^= (uint8_t)s[i];
    if (cs != (uint8_t)((hi << 4) | lo)) {
        f->seq = peek_seq(s, body);
        return -E_CHECKSUM;
    }
    int8_t r = parse_body(s, body, f);
    if (r < 0) {
        uint16_t seq = peek_seq(s, body);
        f->seq = seq;
    }
    return r;
}

int8_t proto_feed(line_rx_t *lr, uint8_t c, frame_t *f)
{
    if (c == '$') {
        int8_t r = 0;
        if (lr->active) {                 /* previous frame never ended */
            f->seq = peek_seq(lr->buf, lr->len);
            f->nargs = 0;
            f->cmd[0] = 0;
            r = -E_TRUNCATED;
        }
        lr->active = 1;
        lr->len = 0;
        return r;
    }
    if (!lr->active)
        return 0;                         /* noise between frames */
    if (c == '\r')
        return 0;
    if (c == '\n') {
        lr->active = 0;
        return finish_line(lr, f);
    }
    if (c < 0x20 || c > 0x7e || lr->len >= PROTO_LINE_MAX) {
        f->seq = peek_seq(lr->buf, lr->len);
        f->nargs = 0;
        f->cmd[0] = 0;
        lr->active = 0;
        return (c < 0x20 || c > 0x7e) ? -E_SYNTAX : -E_TRUNCATED;
    }
    lr->buf[lr->len++] = (char)c;
    return 0;
}

/* ---- outgoing ----------------------------------------------------- */

static void put(tx_frame_t *t, char c)
{
    if (t->len < PROTO_TX_MAX - 4) {          /* room for "*HH\n" */
        t->buf[t->len++] = c;
        t->cs ^= (uint8_t)c;
    }
}

/* decimal without division (a 32-bit division is slow on an 8-bit MCU):
 * subtract powers of ten */
static const uint32_t pow10[] = {
    1000000000UL, 100000000UL, 10000000UL, 1000000UL, 100000UL,
    10000UL, 1000UL, 100UL, 10UL, 1UL,
};

static void put_udec(tx_frame_t *t, uint32_t v)
{
    uint8_t started = 0;
    for (uint8_t i = 0; i < sizeof(pow10) / sizeof(pow10[0]); i++) {
        uint32_t p = pow10[i];
        char d = '0';
        while (v >= p) {
            v -= p;
            d++;
        }
        if (d != '0' || started || p == 1UL) {
            put(t, d);
            started = 1;
        }
    }
}

void tx_begin(tx_frame_t *t, uint16_t seq, const char *kind)
{
    t->len = 0;
    t->cs = 0;
    t->buf[t->len++] = '$';
    put_udec(t, seq);
    tx_str(t, kind);
}

void tx_str(tx_frame_t *t, const char *s)
{
    put(t, ',');
    while (*s)
        put(t, *s++);
}

void tx_int(tx_frame_t *t, int32_t v)
{
    put(t, ',');
    if (v < 0) {
        put(t, '-');
        put_udec(t, (uint32_t)(-(v + 1)) + 1u);
    } else {
        put_udec(t, (uint32_t)v);
    }
}

static const char hexd[] = "0123456789ABCDEF";

void tx_hex(tx_frame_t *t, uint16_t v)
{
    put(t, ',');
    uint8_t started = 0;
    for (int8_t sh = 12; sh >= 0; sh -= 4) {
        uint8_t d = (uint8_t)((v >> sh) & 0xF);
        if (d || started || sh == 0) {
            put(t, hexd[d]);
            started = 1;
        }
    }
}

const char *tx_finish(tx_frame_t *t)
{
    uint8_t cs = t->cs;
    t->buf[t->len++] = '*';
    t->buf[t->len++] = hexd[cs >> 4];
    t->buf[t->len++] = hexd[cs & 0xF];
    t->buf[t->len++] = '\n';
    t->buf[t->len] = 0;
    return t->buf;
}

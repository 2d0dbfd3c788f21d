/*
 * protocol.h - line protocol framing (see PROTOCOL.md).
 *
 *   frame    = "$" seq "," CMD *("," arg) "*" HH "\n"
 *   HH       = XOR of every byte strictly between "$" and "*", two
 *              upper-case hex digits
 *
 * Pure C (no AVR headers): the same file builds on a host for tests.
 */
#ifndef CTR_PROTOCOL_H
#define CTR_PROTOCOL_H
#include <stdint.h>

#define PROTO_LINE_MAX   64   /* bytes between '$' and '\n' (received)  */
#define PROTO_TX_MAX     96   /* bytes of a sent frame, '$' to '\n'     */
#define PROTO_MAX_ARGS   4
#define PROTO_CMD_MAX    7

/* error codes sent as $<seq>,ERR,<code>,<text>*HH */
enum proto_err {
    E_OK         = 0,
    E_CHECKSUM   = 1,   /* BADCS    checksum mismatch                  */
    E_SYNTAX     = 2,   /* SYNTAX   malformed frame                    */
    E_UNKNOWN    = 3,   /* UNKNOWN  unknown command                    */
    E_LIMIT      = 4,   /* LIMIT    target outside the soft limits     */
    E_NOT_HOMED  = 5,   /* NOTHOMED MOV before HOME completed          */
    E_BUSY       = 6,   /* BUSY     homing in progress                 */
    E_TRUNCATED  = 7,   /* TRUNC    frame cut short or too long        */
    E_ARG        = 8,   /* BADARG   wrong number / range of arguments  */
};

const char *proto_err_text(uint8_t code);

typedef struct {
    uint16_t seq;
    char cmd[PROTO_CMD_MAX + 1];
    uint8_t nargs;
    int32_t args[PROTO_MAX_ARGS];
} frame_t;

typedef struct {
    char buf[PROTO_LINE_MAX + 1];
    uint8_t len;
    uint8_t active;
} line_rx_t;

void proto_rx_init(line_rx_t *lr);

/*
 * Feed one received byte.
 * returns  0: nothing complete yet (bytes outside a frame are ignored)
 *          1: a valid frame was decoded into *f
 *        < 0: -error code; f->seq holds the sequence number when it
 *             could be read, 0 otherwise
 */
int8_t proto_feed(line_rx_t *lr, uint8_t c, frame_t *f);

/* outgoing frame builder */
typedef struct {
    char buf[PROTO_TX_MAX + 1];
    uint8_t len;
    uint8_t cs;
} tx_frame_t;

void tx_begin(tx_frame_t *t, uint16_t seq, const char *kind);
void tx_str(tx_frame_t *t, const char *s);     /* appends ",s"      */
void tx_int(tx_frame_t *t, int32_t v);         /* appends ",<dec>"  */
void tx_hex(tx_frame_t *t, uint16_t v);        /* appends ",<HEX>"  */
const char *tx_finish(tx_frame_t *t);          /* "*HH\n", returns buf */

#endif

/*
 * motor_card.h - the motor_id serial card protocol in portable C99 (header only).
 *
 * The authority is motor_id/card/protocol.py (specification: docs/protocol.md); the
 * card's behaviour follows motor_id/card/simulator.py (VirtualCard). This header holds:
 *
 *   - CRC-32 exactly as zlib.crc32 (reflected polynomial 0xEDB88320, init and final
 *     xor 0xFFFFFFFF), bitwise, integers only;
 *   - frame encoders for samples and replies, byte by byte little-endian;
 *   - mc_parse_command(): one complete host -> card frame to a command or an error
 *     kind, checked in the order of protocol.parse_command;
 *   - mc_rx: the host -> card byte stream splitter (protocol.CommandParser), fed one
 *     byte at a time from a fixed 64-byte buffer;
 *   - mc_clock: a 64-bit card clock [us] from a wrapping 32-bit micros() counter;
 *   - mc_card: the card (commands, replies, the paper_steps and bipolar_steps
 *     profiles, sampling schedule, command watchdog, voltage limit). The watchdog
 *     stops a held voltage and a running profile alike when no command (a ping will
 *     do) arrives for watchdog_us: a host that dies mid-profile leaves the motor at 0 V.
 *
 * No dynamic allocation, no I/O, no struct casting; compiles as C99 and as C++ (for
 * Arduino sketches). Floats are IEEE-754 binary32; profile times and levels use
 * double, which matches the Python side bit for bit where double is binary64 (hosts,
 * ARM); on AVR double is binary32 and a profile value may differ in the last bit.
 */
#ifndef MOTOR_CARD_H
#define MOTOR_CARD_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#ifdef __cplusplus
extern "C" {
#endif

#define MC_API static inline

/* -- constants (protocol.py) ------------------------------------------------------- */

#define MC_SYNC0 0xA5u
#define MC_SYNC1 0x5Au
#define MC_OVERHEAD 8u              /* sync 2, type 1, len 1, CRC 4 */

#define MC_TYPE_SAMPLE 0x01u
#define MC_TYPE_REPLY 0x02u
#define MC_TYPE_SET_VOLTAGE 0x10u
#define MC_TYPE_START_PROFILE 0x11u
#define MC_TYPE_STOP 0x12u
#define MC_TYPE_SET_PERIOD 0x13u
#define MC_TYPE_PING 0x14u

#define MC_FLAG_CURRENT 0x0001u
#define MC_FLAG_PROFILE 0x0002u
#define MC_FLAG_PROFILE_END 0x0004u
#define MC_FLAG_STARTUP 0x0008u
#define MC_FLAG_OVERRUN 0x0010u

#define MC_STATUS_OK 0u
#define MC_STATUS_BAD_VALUE 1u
#define MC_STATUS_UNKNOWN_PROFILE 2u
#define MC_STATUS_BUSY 3u
#define MC_STATUS_UNSUPPORTED 4u

#define MC_SAMPLE_LEN 22u           /* payload without current */
#define MC_SAMPLE_LEN_I 26u         /* payload with current */
#define MC_REPLY_LEN 6u
#define MC_PROFILE_HEAD 13u         /* amplitude, duration, seed, name length */
#define MC_MAX_NAME 32u
#define MC_MAX_COMMAND_FRAME (MC_OVERHEAD + MC_PROFILE_HEAD + MC_MAX_NAME)   /* 53 */
#define MC_SAMPLE_FRAME_MAX (MC_OVERHEAD + MC_SAMPLE_LEN_I)                  /* 34 */
#define MC_REPLY_FRAME (MC_OVERHEAD + MC_REPLY_LEN)                          /* 14 */

/* Limits of the simulated card (simulator.py), the defaults of mc_config. */
#define MC_MIN_PERIOD_US 100u
#define MC_MAX_PERIOD_US 10000000u
#define MC_MAX_PROFILE_SAMPLES 10000000.0

/* ProtocolError.kind values; MC_OK is no error. */
typedef enum {
    MC_OK = 0,
    MC_ERR_SHORT,
    MC_ERR_BAD_SYNC,
    MC_ERR_BAD_LENGTH,
    MC_ERR_BAD_CRC,
    MC_ERR_BAD_TYPE,
    MC_ERR_BAD_VALUE,
    MC_ERR_COUNT
} mc_error;

MC_API const char *mc_error_name(mc_error e)
{
    static const char *const names[MC_ERR_COUNT] = {
        "ok", "short", "bad_sync", "bad_length", "bad_crc", "bad_type", "bad_value"};
    return ((unsigned)e < (unsigned)MC_ERR_COUNT) ? names[e] : "?";
}

/* -- CRC-32 (zlib.crc32) ------------------------------------------------------------ */

/* Continue a CRC: start with crc = 0, pass the result back in for the next chunk. */
MC_API uint32_t mc_crc32_update(uint32_t crc, const uint8_t *data, size_t n)
{
    size_t i;
    int bit;
    crc = ~crc;
    for (i = 0; i < n; ++i) {
        crc ^= data[i];
        for (bit = 0; bit < 8; ++bit) {
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

MC_API uint32_t mc_crc32(const uint8_t *data, size_t n)
{
    return mc_crc32_update(0u, data, n);
}

/* -- little-endian fields, byte by byte --------------------------------------------- */

MC_API void mc_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

MC_API void mc_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)((v >> 8) & 0xFFu);
    p[2] = (uint8_t)((v >> 16) & 0xFFu);
    p[3] = (uint8_t)(v >> 24);
}

MC_API void mc_put_u64(uint8_t *p, uint64_t v)
{
    mc_put_u32(p, (uint32_t)(v & 0xFFFFFFFFu));
    mc_put_u32(p + 4, (uint32_t)(v >> 32));
}

MC_API uint32_t mc_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

/* binary32 <-> its bit pattern (memcpy: the portable way, no pointer casts) */
MC_API uint32_t mc_float_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

MC_API float mc_bits_float(uint32_t u)
{
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

/* True for infinities and NaNs, decided on the bits (no float arithmetic). */
MC_API int mc_bits_nonfinite(uint32_t u)
{
    return (u & 0x7F800000u) == 0x7F800000u;
}

/* Frame around a payload already written at out + 4: header and CRC. Returns its size. */
MC_API size_t mc_finish_frame(uint8_t *out, uint8_t type, uint8_t len)
{
    out[0] = MC_SYNC0;
    out[1] = MC_SYNC1;
    out[2] = type;
    out[3] = len;
    mc_put_u32(out + 4 + len, mc_crc32(out + 2, (size_t)len + 2u));
    return (size_t)len + MC_OVERHEAD;
}

/* -- encoders (card -> host) --------------------------------------------------------- */

/*
 * Sample frame into out (>= MC_SAMPLE_FRAME_MAX bytes). The current field is present
 * iff has_current; the MC_FLAG_CURRENT bit is set or cleared to match, as
 * protocol.encode_sample does. Returns the frame size (30 or 34), or 0 when voltage,
 * speed or current is not finite (the Python encoder refuses those too).
 */
MC_API size_t mc_encode_sample(uint8_t *out, uint32_t seq, uint64_t t_us, uint16_t flags,
                               float voltage, float speed, int has_current, float current)
{
    uint32_t v = mc_float_bits(voltage), w = mc_float_bits(speed), i = mc_float_bits(current);
    uint8_t *p = out + 4;
    if (mc_bits_nonfinite(v) || mc_bits_nonfinite(w) || (has_current && mc_bits_nonfinite(i))) {
        return 0;
    }
    flags = has_current ? (uint16_t)(flags | MC_FLAG_CURRENT)
                        : (uint16_t)(flags & (uint16_t)~MC_FLAG_CURRENT);
    mc_put_u32(p, seq);
    mc_put_u64(p + 4, t_us);
    mc_put_u16(p + 12, flags);
    mc_put_u32(p + 14, v);
    mc_put_u32(p + 18, w);
    if (has_current) {
        mc_put_u32(p + 22, i);
    }
    return mc_finish_frame(out, MC_TYPE_SAMPLE,
                           (uint8_t)(has_current ? MC_SAMPLE_LEN_I : MC_SAMPLE_LEN));
}

/* Reply frame (MC_REPLY_FRAME = 14 bytes) to the command of type code `command`. */
MC_API size_t mc_encode_reply(uint8_t *out, uint8_t command, uint8_t status, uint32_t value)
{
    out[4] = command;
    out[5] = status;
    mc_put_u32(out + 6, value);
    return mc_finish_frame(out, MC_TYPE_REPLY, (uint8_t)MC_REPLY_LEN);
}

/* -- commands (host -> card) --------------------------------------------------------- */

typedef struct {
    uint8_t type;                  /* MC_TYPE_SET_VOLTAGE .. MC_TYPE_PING */
    float voltage;                 /* set_voltage [V] */
    float amplitude;               /* start_profile [V] */
    float duration;                /* start_profile [s] */
    uint32_t seed;                 /* start_profile */
    uint8_t name_len;              /* start_profile, 1..32 */
    char name[MC_MAX_NAME + 1];    /* start_profile, NUL-terminated printable ASCII */
    uint32_t period_us;            /* set_period [us] */
    uint32_t token;                /* ping */
} mc_command;

/* Is `len` a payload length the host -> card frame type `type` allows? */
MC_API int mc_host_length_ok(uint8_t type, uint8_t len)
{
    switch (type) {
    case MC_TYPE_SET_VOLTAGE:
    case MC_TYPE_SET_PERIOD:
    case MC_TYPE_PING:
        return len == 4u;
    case MC_TYPE_START_PROFILE:
        return len > MC_PROFILE_HEAD && len <= MC_PROFILE_HEAD + MC_MAX_NAME;
    case MC_TYPE_STOP:
        return len == 0u;
    default:
        return 0;
    }
}

MC_API int mc_host_type_ok(uint8_t type)
{
    return type >= MC_TYPE_SET_VOLTAGE && type <= MC_TYPE_PING;
}

/* Decode a payload whose type and length are known to be valid (protocol._decode). */
MC_API mc_error mc_decode_payload(uint8_t type, const uint8_t *p, uint8_t len, mc_command *c)
{
    uint32_t a, d;
    uint8_t k;
    memset(c, 0, sizeof *c);
    c->type = type;
    switch (type) {
    case MC_TYPE_SET_VOLTAGE:
        a = mc_get_u32(p);
        if (mc_bits_nonfinite(a)) {
            return MC_ERR_BAD_VALUE;
        }
        c->voltage = mc_bits_float(a);
        return MC_OK;
    case MC_TYPE_START_PROFILE:
        if (p[12] != (uint8_t)(len - MC_PROFILE_HEAD)) {
            return MC_ERR_BAD_LENGTH;
        }
        for (k = 0; k < p[12]; ++k) {
            if (p[MC_PROFILE_HEAD + k] < 0x20u || p[MC_PROFILE_HEAD + k] > 0x7Eu) {
                return MC_ERR_BAD_VALUE;
            }
            c->name[k] = (char)p[MC_PROFILE_HEAD + k];
        }
        a = mc_get_u32(p);
        d = mc_get_u32(p + 4);
        if (mc_bits_nonfinite(a) || mc_bits_nonfinite(d)) {
            return MC_ERR_BAD_VALUE;
        }
        c->name_len = p[12];
        c->amplitude = mc_bits_float(a);
        c->duration = mc_bits_float(d);
        c->seed = mc_get_u32(p + 8);
        return MC_OK;
    case MC_TYPE_SET_PERIOD:
        c->period_us = mc_get_u32(p);
        return c->period_us == 0u ? MC_ERR_BAD_VALUE : MC_OK;
    case MC_TYPE_PING:
        c->token = mc_get_u32(p);
        return MC_OK;
    default: /* MC_TYPE_STOP */
        return MC_OK;
    }
}

/*
 * Decode one complete frame (sync to CRC) as protocol.parse_command does, with the
 * same error kinds in the same order: short, bad_sync, short / bad_length (size vs
 * header), bad_crc, bad_type, bad_length (payload vs type), bad_value.
 */
MC_API mc_error mc_parse_command(const uint8_t *f, size_t n, mc_command *c)
{
    size_t want;
    if (n < MC_OVERHEAD) {
        return MC_ERR_SHORT;
    }
    if (f[0] != MC_SYNC0 || f[1] != MC_SYNC1) {
        return MC_ERR_BAD_SYNC;
    }
    want = (size_t)f[3] + MC_OVERHEAD;
    if (n < want) {
        return MC_ERR_SHORT;
    }
    if (n > want) {
        return MC_ERR_BAD_LENGTH;
    }
    if (mc_crc32(f + 2, want - 6u) != mc_get_u32(f + want - 4u)) {
        return MC_ERR_BAD_CRC;
    }
    if (!mc_host_type_ok(f[2])) {
        return MC_ERR_BAD_TYPE;
    }
    if (!mc_host_length_ok(f[2], f[3])) {
        return MC_ERR_BAD_LENGTH;
    }
    return mc_decode_payload(f[2], f + 4, f[3], c);
}

/* -- byte stream splitter (protocol.CommandParser) ---------------------------------- */

#define MC_RX_BUF 64u   /* longest command frame 53 + 2 look-ahead bytes, rounded up */

typedef struct {
    uint8_t buf[MC_RX_BUF];
    uint8_t len;
    uint32_t garbage_bytes;          /* bytes skipped outside valid frames */
    uint32_t frames;                 /* commands decoded */
    uint32_t errors[MC_ERR_COUNT];   /* ProtocolError count by kind */
} mc_rx;

enum { MC_RX_NONE = 0, MC_RX_COMMAND = 1, MC_RX_ERROR = 2 };

MC_API void mc_rx_init(mc_rx *rx)
{
    memset(rx, 0, sizeof *rx);
}

MC_API void mc_rx_drop(mc_rx *rx, uint8_t n)
{
    memmove(rx->buf, rx->buf + n, (size_t)(rx->len - n));
    rx->len = (uint8_t)(rx->len - n);
}

/*
 * Append one received byte. Call mc_rx_next() until it returns MC_RX_NONE before the
 * next byte; if that was not done and the buffer is full, the oldest byte is dropped
 * and counted as garbage.
 */
MC_API void mc_rx_push(mc_rx *rx, uint8_t byte)
{
    if (rx->len == MC_RX_BUF) {
        mc_rx_drop(rx, 1u);
        rx->garbage_bytes++;
    }
    rx->buf[rx->len++] = byte;
}

/*
 * The next item of the stream: MC_RX_COMMAND (filled *cmd), MC_RX_ERROR (*err set) or
 * MC_RX_NONE (more bytes needed). `final` settles the end of a stream (flush(): a
 * pending bad CRC frame is reported, a leftover partial frame is `short`). The scan
 * is protocol._StreamSplitter._items, one item per call.
 */
MC_API int mc_rx_next(mc_rx *rx, int final, mc_command *cmd, mc_error *err)
{
    uint8_t *b = rx->buf;
    unsigned pos = 0, end, len;
    int item = MC_RX_NONE;
    for (;;) {
        unsigned i = pos;
        while (i + 1u < rx->len && !(b[i] == MC_SYNC0 && b[i + 1u] == MC_SYNC1)) {
            ++i;
        }
        if (i + 1u >= rx->len) {
            /* no marker: keep a trailing unconsumed 0xA5 that may start one */
            unsigned keep = (!final && pos < rx->len && b[rx->len - 1u] == MC_SYNC0) ? 1u : 0u;
            rx->garbage_bytes += rx->len - pos - keep;
            pos = rx->len - keep;
            break;
        }
        rx->garbage_bytes += i - pos;
        pos = i;
        if (rx->len - pos < 4u) {
            break;
        }
        if (!mc_host_type_ok(b[pos + 2u]) || !mc_host_length_ok(b[pos + 2u], b[pos + 3u])) {
            rx->garbage_bytes++;        /* a sync pattern inside garbage */
            pos++;
            continue;
        }
        len = b[pos + 3u];
        end = pos + MC_OVERHEAD + len;
        if (rx->len < end) {
            break;
        }
        if (mc_crc32(b + pos + 2u, len + 2u) != mc_get_u32(b + end - 4u)) {
            if (rx->len < end + 2u && !final) {
                break;                  /* wait: does the next frame follow right after? */
            }
            *err = MC_ERR_BAD_CRC;
            item = MC_RX_ERROR;
            if (rx->len == end ||
                (rx->len >= end + 2u && b[end] == MC_SYNC0 && b[end + 1u] == MC_SYNC1)) {
                pos = end;
            } else {
                rx->garbage_bytes++;    /* torn frame or corrupted length: rescan */
                pos++;
            }
            break;
        }
        *err = mc_decode_payload(b[pos + 2u], b + pos + 4u, (uint8_t)len, cmd);
        item = (*err == MC_OK) ? MC_RX_COMMAND : MC_RX_ERROR;
        pos = end;
        break;
    }
    mc_rx_drop(rx, (uint8_t)pos);
    if (item == MC_RX_NONE && final && rx->len) {
        *err = MC_ERR_SHORT;
        item = MC_RX_ERROR;
        rx->len = 0;
    }
    if (item == MC_RX_COMMAND) {
        rx->frames++;
    } else if (item == MC_RX_ERROR) {
        rx->errors[*err]++;
    }
    return item;
}

/* -- card clock: 64-bit microseconds from a wrapping 32-bit counter ------------------ */

typedef struct {
    uint32_t last;     /* last raw counter value */
    uint64_t now;      /* card time [us] since mc_clock_init */
} mc_clock;

MC_API void mc_clock_init(mc_clock *clk, uint32_t micros_now)
{
    clk->last = micros_now;
    clk->now = 0u;
}

/*
 * Card time [us] of a raw reading of micros(). The unsigned difference to the last
 * reading is right across the 2^32 wrap (every ~71.6 min); a difference of 2^31 or
 * more is read as a reading older than the last one (latched by an interrupt before
 * the main loop read the counter): its time is returned and the clock does not move.
 * So readings must come at least every 2^31 us (~35.8 min).
 */
MC_API uint64_t mc_clock_update(mc_clock *clk, uint32_t micros_now)
{
    uint32_t d = micros_now - clk->last;
    if (d >= 0x80000000u) {
        d = clk->last - micros_now;
        return d > clk->now ? 0u : clk->now - d;
    }
    clk->now += d;
    clk->last = micros_now;
    return clk->now;
}

/* -- profiles (motor_id.excitation) -------------------------------------------------- */

enum { MC_PROFILE_NONE = 0, MC_PROFILE_PAPER_STEPS, MC_PROFILE_BIPOLAR_STEPS };

/* The paper's Eq. 14 input: 0, 3.8, 7, 9 V from 0, 3, 16, 28 s, scaled by amplitude / 9. */
MC_API float mc_paper_steps(double t, double amplitude)
{
    static const double start[4] = {0.0, 3.0, 16.0, 28.0};
    static const double level[4] = {0.0, 3.8, 7.0, 9.0};
    double u = 0.0;
    int k;
    for (k = 0; k < 4; ++k) {
        if (t >= start[k]) {
            u = level[k] * amplitude / 9.0;
        }
    }
    return (float)u;
}

/* excitation.bipolar_steps with its default 4 s period (2 s per level). */
MC_API float mc_bipolar_steps(double t, double amplitude)
{
    static const double level[8] = {0.0, 0.5, 1.0, 0.0, -0.5, -1.0, 0.25, -0.25};
    double k = floor(t / 2.0);
    return (float)(level[(unsigned)fmod(k, 8.0)] * amplitude);
}

/* Profile name (as on the wire) -> MC_PROFILE_*; -1: a host profile this card lacks. */
MC_API int mc_profile_id(const char *name, uint8_t n)
{
    static const char *const known[4] = {"paper_steps", "bipolar_steps", "prbs", "multisine"};
    int k;
    for (k = 0; k < 4; ++k) {
        if (strlen(known[k]) == n && memcmp(known[k], name, n) == 0) {
            return k < 2 ? k + 1 : -1;
        }
    }
    return MC_PROFILE_NONE;
}

/* -- the card ------------------------------------------------------------------------ */

typedef struct {
    uint32_t period_us;     /* initial sample period, MC_MIN_PERIOD_US .. MC_MAX_PERIOD_US */
    double v_limit;         /* largest |voltage| and |amplitude| accepted [V] */
    uint32_t watchdog_us;   /* 0 V after this long without a command while a held voltage
                               or a profile drives the motor; 0 off */
    int with_current;       /* send the current field */
} mc_config;

/* The simulated card's settings: 10 ms, 100 V, no watchdog, with current. */
MC_API mc_config mc_default_config(void)
{
    mc_config c;
    c.period_us = 10000u;
    c.v_limit = 100.0;
    c.watchdog_us = 0u;
    c.with_current = 1;
    return c;
}

enum { MC_MODE_IDLE = 0, MC_MODE_EXTERNAL, MC_MODE_PROFILE };

typedef struct {
    mc_config cfg;
    mc_clock clock;
    mc_rx rx;
    uint32_t period_us;
    uint32_t seq;             /* sequence number of the next sample */
    uint64_t next_due;        /* card time of the next sampling deadline [us] */
    uint64_t last_t;          /* card time of the last sample [us] */
    uint64_t last_cmd;        /* card time of the last decoded command [us] */
    float hold;               /* input held outside a profile [V] */
    uint8_t mode;             /* MC_MODE_* */
    uint8_t startup;          /* next sample is the first */
    uint8_t overrun;          /* next sample follows a missed deadline */
    uint8_t profile;          /* MC_PROFILE_* while mode == MC_MODE_PROFILE */
    double amplitude;         /* profile amplitude [V] */
    uint32_t profile_start;   /* seq of the profile's first sample */
    uint32_t profile_n;       /* profile length in samples */
    uint32_t watchdog_trips;  /* times the watchdog forced 0 V */
} mc_card;

/* Start the card at card time 0 = the raw counter value micros_now. Returns 0 if cfg is
 * out of range (period outside 100 us .. 10 s, v_limit not > 0). */
MC_API int mc_card_init(mc_card *c, const mc_config *cfg, uint32_t micros_now)
{
    if (cfg->period_us < MC_MIN_PERIOD_US || cfg->period_us > MC_MAX_PERIOD_US ||
        !(cfg->v_limit > 0.0)) {
        return 0;
    }
    memset(c, 0, sizeof *c);
    c->cfg = *cfg;
    c->period_us = cfg->period_us;
    c->startup = 1u;
    mc_clock_init(&c->clock, micros_now);
    mc_rx_init(&c->rx);
    return 1;
}

MC_API int mc_card_profile_running(const mc_card *c)
{
    return c->mode == MC_MODE_PROFILE && (uint32_t)(c->seq - c->profile_start) < c->profile_n;
}

MC_API int mc_input_ok(const mc_card *c, float v)
{
    return !mc_bits_nonfinite(mc_float_bits(v)) && fabs((double)v) <= c->cfg.v_limit;
}

MC_API uint8_t mc_card_start_profile(mc_card *c, const mc_command *cmd)
{
    int id = mc_profile_id(cmd->name, cmd->name_len);
    double period_s = (double)c->period_us / 1e6;
    double n = ceil((double)cmd->duration / period_s - 1e-9);
    if (id == MC_PROFILE_NONE) {
        return MC_STATUS_UNKNOWN_PROFILE;
    }
    if (id < 0) {
        return MC_STATUS_UNSUPPORTED;       /* prbs, multisine: host-side RNG */
    }
    if (!(mc_input_ok(c, cmd->amplitude) && n > 0.0 && n <= MC_MAX_PROFILE_SAMPLES)) {
        return MC_STATUS_BAD_VALUE;
    }
    c->mode = MC_MODE_PROFILE;
    c->profile = (uint8_t)id;
    c->amplitude = (double)cmd->amplitude;
    c->profile_start = c->seq;
    c->profile_n = (uint32_t)n;
    c->hold = 0.0f;
    return MC_STATUS_OK;
}

/* New period from the next sample on: that sample comes one new period after the last
 * (at once, flagged as an overrun, if that instant has already passed). */
MC_API uint8_t mc_card_set_period(mc_card *c, uint32_t period_us)
{
    if (mc_card_profile_running(c)) {
        return MC_STATUS_BUSY;
    }
    if (period_us < MC_MIN_PERIOD_US || period_us > MC_MAX_PERIOD_US) {
        return MC_STATUS_BAD_VALUE;
    }
    if (!c->startup) {
        c->next_due = c->last_t + period_us;   /* next sample one new period after the last */
    }
    c->period_us = period_us;
    return MC_STATUS_OK;
}

/*
 * Execute one decoded command at card time now_us from the next sample on; write the
 * reply frame (MC_REPLY_FRAME bytes) to out. Every command feeds the watchdog.
 */
MC_API size_t mc_card_handle(mc_card *c, const mc_command *cmd, uint64_t now_us, uint8_t *out)
{
    uint8_t status = MC_STATUS_OK;
    uint32_t value = c->seq;
    c->last_cmd = now_us;
    switch (cmd->type) {
    case MC_TYPE_SET_VOLTAGE:
        if (!mc_input_ok(c, cmd->voltage)) {
            status = MC_STATUS_BAD_VALUE;
        } else {
            c->hold = cmd->voltage;
            c->mode = MC_MODE_EXTERNAL;
        }
        break;
    case MC_TYPE_START_PROFILE:
        status = mc_card_start_profile(c, cmd);
        break;
    case MC_TYPE_STOP:
        c->hold = 0.0f;
        c->mode = MC_MODE_IDLE;
        break;
    case MC_TYPE_SET_PERIOD:
        status = mc_card_set_period(c, cmd->period_us);
        break;
    case MC_TYPE_PING:
        value = cmd->token;
        break;
    default:
        status = MC_STATUS_UNSUPPORTED;
        break;
    }
    return mc_encode_reply(out, cmd->type, status, value);
}

/* Give the card one received byte; then call mc_card_poll_rx() until it returns 0. */
MC_API void mc_card_rx_byte(mc_card *c, uint8_t byte)
{
    mc_rx_push(&c->rx, byte);
}

/* The next reply to send (its size, written to out, >= MC_REPLY_FRAME bytes), or 0 when
 * the received bytes hold no further command. Bad frames are counted in c->rx. */
MC_API size_t mc_card_poll_rx(mc_card *c, uint32_t micros_now, uint8_t *out)
{
    mc_command cmd;
    mc_error err = MC_OK;
    int item;
    uint64_t now = mc_clock_update(&c->clock, micros_now);
    while ((item = mc_rx_next(&c->rx, 0, &cmd, &err)) != MC_RX_NONE) {
        if (item == MC_RX_COMMAND) {
            return mc_card_handle(c, &cmd, now, out);
        }
    }
    return 0;
}

/*
 * Is a sample due at raw counter value micros_now? If so, *t_us is its card time (the
 * reading itself) and the deadline moves on by one period; deadlines already missed
 * are skipped and the sample carries MC_FLAG_OVERRUN.
 */
MC_API int mc_card_due(mc_card *c, uint32_t micros_now, uint64_t *t_us)
{
    uint64_t now = mc_clock_update(&c->clock, micros_now);
    if (now < c->next_due) {
        return 0;
    }
    c->next_due += c->period_us;
    if (now >= c->next_due) {
        c->overrun = 1u;
        c->next_due += ((now - c->next_due) / c->period_us + 1u) * c->period_us;
    }
    *t_us = now;
    return 1;
}

/* Is the host silent for the watchdog time while a held voltage or a profile drives? */
MC_API int mc_card_watchdog_due(const mc_card *c, uint64_t t_us)
{
    int driving = c->mode == MC_MODE_EXTERNAL || mc_card_profile_running(c);
    return driving && c->cfg.watchdog_us && t_us >= c->last_cmd &&
           t_us - c->last_cmd >= c->cfg.watchdog_us;
}

/*
 * The input for the sample about to be taken and its profile flags (advances nothing
 * but the watchdog: a silent host stops the motor, a held voltage or a profile alike).
 */
MC_API float mc_card_input(mc_card *c, uint64_t t_us, uint16_t *flags)
{
    *flags = 0u;
    if (mc_card_watchdog_due(c, t_us)) {
        c->hold = 0.0f;                      /* the host went silent: stop the motor */
        c->mode = MC_MODE_IDLE;
        c->watchdog_trips++;
    }
    if (mc_card_profile_running(c)) {
        uint32_t k = c->seq - c->profile_start;
        double t = (double)k * ((double)c->period_us / 1e6);
        *flags = MC_FLAG_PROFILE;
        if (k == c->profile_n - 1u) {
            *flags |= MC_FLAG_PROFILE_END;
        }
        return c->profile == MC_PROFILE_PAPER_STEPS ? mc_paper_steps(t, c->amplitude)
                                                    : mc_bipolar_steps(t, c->amplitude);
    }
    return c->hold;
}

/*
 * Take the sample at card time t_us (from mc_card_due): choose the input held from now
 * to the next sample (returned in *u: apply it to the motor now), encode the frame
 * with the speed [rad/s] and current [A] measured at t_us into out
 * (>= MC_SAMPLE_FRAME_MAX bytes). Returns the frame size; 0 when a measurement is not
 * finite (nothing to send, the sequence number is used up: the host sees a gap).
 */
MC_API size_t mc_card_sample(mc_card *c, uint64_t t_us, float speed, float current,
                             uint8_t *out, float *u)
{
    uint16_t flags;
    size_t n;
    *u = mc_card_input(c, t_us, &flags);
    if (c->startup) {
        flags |= MC_FLAG_STARTUP;
    }
    if (c->overrun) {
        flags |= MC_FLAG_OVERRUN;
    }
    n = mc_encode_sample(out, c->seq, t_us, flags, *u, speed, c->cfg.with_current, current);
    c->startup = 0u;
    c->overrun = 0u;
    c->last_t = t_us;
    c->seq++;
    return n;
}

#ifdef __cplusplus
}
#endif

#endif /* MOTOR_CARD_H */

/*
 * host_main.c - drive firmware/motor_card.h from a pipe (used by test/test_firmware.py).
 *
 * One request per line on stdin, one answer line on stdout. Numbers are decimal, byte
 * strings and float bit patterns hex ("-" for none):
 *
 *   crc HEX                          -> crc32 as 8 hex digits
 *   enc SEQ T_US FLAGS VBITS WBITS HAS_I IBITS
 *                                    -> sample frame hex, or "none"
 *   reply CMD STATUS VALUE           -> reply frame hex
 *   parse HEX                        -> "ok DESC" or "err KIND" (mc_parse_command)
 *   feed HEX / flush                 -> stream splitter: "GARBAGE ITEM..." with ITEM
 *                                       "c:DESC" or "e:KIND"
 *   init PERIOD_US VLIMIT WATCHDOG_US WITH_I MICROS0
 *                                    -> "ok" or "err"
 *   rx MICROS HEX                    -> card: the reply frames, concatenated hex, or "-"
 *   tick MICROS WBITS IBITS          -> card: "none" or "T_US FRAMEHEX UBITS"
 *   clock MICROS                     -> card time [us]
 *   stat                             -> "GARBAGE FRAMES ERR1..ERR6 WATCHDOG_TRIPS"
 *
 * DESC: set_voltage:VBITS, start_profile:ABITS:DBITS:SEED:NAMEHEX, stop,
 * set_period:US, ping:TOKEN.
 */
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../motor_card.h"

#define LINE_MAX_CHARS 70000
#define BYTES_MAX 32768

static char line[LINE_MAX_CHARS];
static uint8_t bytes[BYTES_MAX];
static mc_rx stream;
static mc_card card;
static int card_ok;

static void put_hex(const uint8_t *p, size_t n)
{
    size_t i;
    if (n == 0) {
        putchar('-');
    }
    for (i = 0; i < n; ++i) {
        printf("%02x", p[i]);
    }
}

static int hex_value(char ch)
{
    if (ch >= '0' && ch <= '9') {
        return ch - '0';
    }
    if (ch >= 'a' && ch <= 'f') {
        return ch - 'a' + 10;
    }
    if (ch >= 'A' && ch <= 'F') {
        return ch - 'A' + 10;
    }
    return -1;
}

/* Parse a hex token ("-" is empty) into bytes; returns the count or -1. */
static long parse_hex(const char *s, uint8_t *out)
{
    long n = 0;
    if (s == NULL) {
        return -1;
    }
    if (strcmp(s, "-") == 0) {
        return 0;
    }
    while (s[0] && s[1]) {
        int hi = hex_value(s[0]), lo = hex_value(s[1]);
        if (hi < 0 || lo < 0 || n >= BYTES_MAX) {
            return -1;
        }
        out[n++] = (uint8_t)(hi * 16 + lo);
        s += 2;
    }
    return s[0] ? -1 : n;
}

static unsigned long long num(const char *s)
{
    return s ? strtoull(s, NULL, 0) : 0u;
}

static void put_command(const mc_command *c)
{
    switch (c->type) {
    case MC_TYPE_SET_VOLTAGE:
        printf("set_voltage:%08" PRIx32, mc_float_bits(c->voltage));
        break;
    case MC_TYPE_START_PROFILE:
        printf("start_profile:%08" PRIx32 ":%08" PRIx32 ":%" PRIu32 ":",
               mc_float_bits(c->amplitude), mc_float_bits(c->duration), c->seed);
        put_hex((const uint8_t *)c->name, c->name_len);
        break;
    case MC_TYPE_STOP:
        printf("stop");
        break;
    case MC_TYPE_SET_PERIOD:
        printf("set_period:%" PRIu32, c->period_us);
        break;
    default:
        printf("ping:%" PRIu32, c->token);
        break;
    }
}

static void drain_stream(int final)
{
    mc_command cmd;
    mc_error err;
    int item;
    printf("%" PRIu32, stream.garbage_bytes);
    while ((item = mc_rx_next(&stream, final, &cmd, &err)) != MC_RX_NONE) {
        if (item == MC_RX_COMMAND) {
            printf(" c:");
            put_command(&cmd);
        } else {
            printf(" e:%s", mc_error_name(err));
        }
    }
    /* the garbage count after the items, so the test sees the final value */
    printf(" g:%" PRIu32, stream.garbage_bytes);
}

static void do_feed(const char *hex)
{
    long n = parse_hex(hex, bytes), i;
    mc_command cmd;
    mc_error err;
    int item;
    if (n < 0) {
        printf("bad input");
        return;
    }
    printf("%" PRIu32, stream.garbage_bytes);
    for (i = 0; i < n; ++i) {
        mc_rx_push(&stream, bytes[i]);
        while ((item = mc_rx_next(&stream, 0, &cmd, &err)) != MC_RX_NONE) {
            if (item == MC_RX_COMMAND) {
                printf(" c:");
                put_command(&cmd);
            } else {
                printf(" e:%s", mc_error_name(err));
            }
        }
    }
    printf(" g:%" PRIu32, stream.garbage_bytes);
}

static void do_rx(const char *micros, const char *hex)
{
    long n = parse_hex(hex, bytes), i;
    uint8_t out[MC_REPLY_FRAME];
    size_t m;
    int any = 0;
    if (n < 0 || !card_ok) {
        printf("bad input");
        return;
    }
    for (i = 0; i < n; ++i) {
        mc_card_rx_byte(&card, bytes[i]);
        while ((m = mc_card_poll_rx(&card, (uint32_t)num(micros), out)) > 0) {
            put_hex(out, m);
            any = 1;
        }
    }
    if (!any) {
        putchar('-');
    }
}

static void do_tick(const char *micros, const char *wbits, const char *ibits)
{
    uint64_t t;
    uint8_t out[MC_SAMPLE_FRAME_MAX];
    float u;
    size_t m;
    if (!card_ok) {
        printf("bad input");
        return;
    }
    if (!mc_card_due(&card, (uint32_t)num(micros), &t)) {
        printf("none");
        return;
    }
    m = mc_card_sample(&card, t, mc_bits_float((uint32_t)num(wbits)),
                       mc_bits_float((uint32_t)num(ibits)), out, &u);
    printf("%" PRIu64 " ", t);
    put_hex(out, m);
    printf(" %08" PRIx32, mc_float_bits(u));
}

static void handle(char *argv[], int argc)
{
    const char *op = argv[0];
    mc_command cmd;
    uint8_t out[MC_SAMPLE_FRAME_MAX];
    long n;
    if (strcmp(op, "crc") == 0) {
        n = parse_hex(argv[1], bytes);
        printf("%08" PRIx32, mc_crc32(bytes, n < 0 ? 0u : (size_t)n));
    } else if (strcmp(op, "enc") == 0 && argc == 8) {
        size_t m = mc_encode_sample(out, (uint32_t)num(argv[1]), (uint64_t)num(argv[2]),
                                    (uint16_t)num(argv[3]),
                                    mc_bits_float((uint32_t)num(argv[4])),
                                    mc_bits_float((uint32_t)num(argv[5])), (int)num(argv[6]),
                                    mc_bits_float((uint32_t)num(argv[7])));
        if (m) {
            put_hex(out, m);
        } else {
            printf("none");
        }
    } else if (strcmp(op, "reply") == 0 && argc == 4) {
        put_hex(out, mc_encode_reply(out, (uint8_t)num(argv[1]), (uint8_t)num(argv[2]),
                                     (uint32_t)num(argv[3])));
    } else if (strcmp(op, "parse") == 0 && argc == 2) {
        mc_error e;
        n = parse_hex(argv[1], bytes);
        e = mc_parse_command(bytes, n < 0 ? 0u : (size_t)n, &cmd);
        if (e == MC_OK) {
            printf("ok ");
            put_command(&cmd);
        } else {
            printf("err %s", mc_error_name(e));
        }
    } else if (strcmp(op, "feed") == 0 && argc == 2) {
        do_feed(argv[1]);
    } else if (strcmp(op, "flush") == 0) {
        drain_stream(1);
    } else if (strcmp(op, "init") == 0 && argc == 6) {
        mc_config cfg = mc_default_config();
        cfg.period_us = (uint32_t)num(argv[1]);
        cfg.v_limit = strtod(argv[2], NULL);
        cfg.watchdog_us = (uint32_t)num(argv[3]);
        cfg.with_current = (int)num(argv[4]);
        card_ok = mc_card_init(&card, &cfg, (uint32_t)num(argv[5]));
        mc_rx_init(&stream);
        printf(card_ok ? "ok" : "err");
    } else if (strcmp(op, "rx") == 0 && argc == 3) {
        do_rx(argv[1], argv[2]);
    } else if (strcmp(op, "tick") == 0 && argc == 4) {
        do_tick(argv[1], argv[2], argv[3]);
    } else if (strcmp(op, "clock") == 0 && argc == 2) {
        printf("%" PRIu64, mc_clock_update(&card.clock, (uint32_t)num(argv[1])));
    } else if (strcmp(op, "stat") == 0) {
        int k;
        printf("%" PRIu32 " %" PRIu32, card.rx.garbage_bytes, card.rx.frames);
        for (k = 1; k < MC_ERR_COUNT; ++k) {
            printf(" %" PRIu32, card.rx.errors[k]);
        }
        printf(" %" PRIu32, card.watchdog_trips);
    } else {
        printf("bad input");
    }
}

int main(void)
{
    char *argv[10];
    int argc;
    while (fgets(line, sizeof line, stdin) != NULL) {
        char *tok = strtok(line, " \t\r\n");
        argc = 0;
        while (tok != NULL && argc < 10) {
            argv[argc++] = tok;
            tok = strtok(NULL, " \t\r\n");
        }
        if (argc > 0) {
            handle(argv, argc);
        }
        putchar('\n');
        fflush(stdout);
    }
    return 0;
}

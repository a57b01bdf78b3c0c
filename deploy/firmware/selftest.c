/*
 * Self-test of courtloc_mcu against test_vectors.h (generated from the Python implementation).
 * Host:   cc -std=c99 -Wall -Wextra -pedantic selftest.c courtloc_mcu.c -o selftest && ./selftest
 * On the MCU: call clm_selftest() once at boot (define CLM_SELFTEST_NO_MAIN) and refuse to arm on a non-zero result.
 */
#include <stdio.h>
#include <string.h>

#include "courtloc_mcu.h"
#include "test_vectors.h"

#define COUNT(a) (sizeof(a) / sizeof((a)[0]))

typedef struct {
    clm_frame_t frames[32];
    size_t n;
} collected_t;

static void collect(const clm_frame_t *frame, void *ctx)
{
    collected_t *c = (collected_t *)ctx;
    if (c->n < COUNT(c->frames))
        c->frames[c->n] = *frame;
    c->n++;
}

static int same_frame(const clm_frame_t *a, const clm_frame_t *b)
{
    return a->seq == b->seq && a->command == b->command && a->rpm == b->rpm && a->flags == b->flags
        && a->reason == b->reason && a->extra_len == b->extra_len && memcmp(a->extra, b->extra, a->extra_len) == 0;
}

static int same_stats(const clm_stats_t *a, const clm_stats_t *b)
{
    return a->frames == b->frames && a->crc_errors == b->crc_errors && a->bad_length == b->bad_length
        && a->unknown_command == b->unknown_command && a->discarded_bytes == b->discarded_bytes;
}

/* Number of failed vectors (0: all pass). */
int clm_selftest(void)
{
    int failed = 0;
    static const uint8_t check[] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
    if (clm_crc16(check, sizeof check, 0xFFFFu) != 0x29B1u)
        failed++;
    for (size_t i = 0; i < COUNT(CLM_ENCODE_VECTORS); i++) {
        uint8_t out[CLM_MAX_FRAME];
        size_t size = clm_encode(&CLM_ENCODE_VECTORS[i].frame, out);
        if (size != CLM_ENCODE_VECTORS[i].size || memcmp(out, CLM_ENCODE_VECTORS[i].bytes, size) != 0)
            failed++;
    }
    for (size_t i = 0; i < COUNT(CLM_ODOMETRY_VECTORS); i++) {
        uint8_t out[CLM_ODOMETRY_FRAME_SIZE];
        size_t size = clm_encode_odometry(&CLM_ODOMETRY_VECTORS[i].odometry, out);
        if (size != CLM_ODOMETRY_FRAME_SIZE || memcmp(out, CLM_ODOMETRY_VECTORS[i].bytes, size) != 0)
            failed++;
    }
    for (size_t i = 0; i < COUNT(CLM_DECODE_VECTORS); i++) {
        for (size_t chunk = 1; chunk <= 7; chunk += 6) { /* byte by byte, and in 7-byte chunks */
            clm_decoder_t decoder;
            collected_t got;
            got.n = 0;
            clm_decoder_init(&decoder);
            for (size_t at = 0; at < CLM_DECODE_VECTORS[i].size; at += chunk) {
                size_t n = CLM_DECODE_VECTORS[i].size - at < chunk ? CLM_DECODE_VECTORS[i].size - at : chunk;
                clm_decoder_feed(&decoder, CLM_DECODE_VECTORS[i].stream + at, n, collect, &got);
            }
            int ok = got.n == CLM_DECODE_VECTORS[i].n_frames && same_stats(&decoder.stats, &CLM_DECODE_VECTORS[i].stats)
                && clm_decoder_buffered(&decoder) == CLM_DECODE_VECTORS[i].buffered;
            for (size_t f = 0; ok && f < got.n; f++)
                ok = same_frame(&got.frames[f], &CLM_DECODE_VECTORS[i].frames[f]);
            if (!ok) {
                failed++;
#ifndef CLM_SELFTEST_NO_MAIN
                printf("FAIL decode '%s' (chunk %u)\n", CLM_DECODE_VECTORS[i].name, (unsigned)chunk);
#endif
            }
        }
    }
    return failed;
}

#ifndef CLM_SELFTEST_NO_MAIN
int main(void)
{
    int failed = clm_selftest();
    size_t total = 1 + COUNT(CLM_ENCODE_VECTORS) + COUNT(CLM_ODOMETRY_VECTORS) + 2 * COUNT(CLM_DECODE_VECTORS);
    printf("%s: %u of %u checks failed\n", failed ? "FAIL" : "ok", (unsigned)failed, (unsigned)total);
    return failed ? 1 : 0;
}
#endif

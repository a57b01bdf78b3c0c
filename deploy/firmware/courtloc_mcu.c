/* courtloc_mcu: see courtloc_mcu.h. */
#include "courtloc_mcu.h"

#include <string.h>

uint16_t clm_crc16(const uint8_t *data, size_t n, uint16_t crc)
{
    /* Bitwise: 8 shifts per byte is cheap at 115200 baud and saves a 512-byte table in flash. */
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)((uint16_t)data[i] << 8);
        for (int bit = 0; bit < 8; bit++)
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

static void put_u16(uint8_t *out, uint16_t value)
{
    out[0] = (uint8_t)(value & 0xFFu);
    out[1] = (uint8_t)(value >> 8);
}

static void put_u32(uint8_t *out, uint32_t value)
{
    put_u16(out, (uint16_t)(value & 0xFFFFu));
    put_u16(out + 2, (uint16_t)(value >> 16));
}

static uint16_t get_u16(const uint8_t *in)
{
    return (uint16_t)(in[0] | (uint16_t)(in[1] << 8));
}

static uint32_t get_u32(const uint8_t *in)
{
    return (uint32_t)get_u16(in) | ((uint32_t)get_u16(in + 2) << 16);
}

/* Two's complement to and from the wire without implementation-defined signed conversions. */
static uint16_t from_i16(int16_t v) { return v < 0 ? (uint16_t)(0xFFFFu - (uint16_t)(-(v + 1))) : (uint16_t)v; }
static uint32_t from_i32(int32_t v) { return v < 0 ? 0xFFFFFFFFu - (uint32_t)(-(v + 1)) : (uint32_t)v; }
static int16_t to_i16(uint16_t u) { return u >= 0x8000u ? (int16_t)(-(int32_t)(0xFFFFu - u) - 1) : (int16_t)u; }
static int32_t to_i32(uint32_t u)
{
    return u >= 0x80000000u ? (int32_t)(-(int64_t)(0xFFFFFFFFu - u) - 1) : (int32_t)u;
}

size_t clm_encode(const clm_frame_t *frame, uint8_t *out)
{
    if (frame->extra_len > CLM_MAX_EXTRA)
        return 0;
    size_t length = CLM_BODY_V1 + frame->extra_len;
    out[0] = CLM_SYNC0;
    out[1] = CLM_SYNC1;
    out[2] = (uint8_t)length;
    put_u16(&out[3], frame->seq);
    out[5] = frame->command;
    put_u16(&out[6], frame->rpm);
    out[8] = frame->flags;
    out[9] = frame->reason;
    memcpy(&out[10], frame->extra, frame->extra_len);
    put_u16(&out[3 + length], clm_crc16(&out[2], 1u + length, 0xFFFFu));
    return 3u + length + 2u;
}

size_t clm_encode_odometry(const clm_odometry_t *odometry, uint8_t out[CLM_ODOMETRY_FRAME_SIZE])
{
    clm_frame_t frame;
    memset(&frame, 0, sizeof frame);
    frame.seq = odometry->seq;
    frame.command = CLM_CMD_ODOMETRY;
    frame.flags = odometry->flags;
    frame.extra_len = CLM_ODOMETRY_PAYLOAD;
    put_u32(&frame.extra[0], odometry->t_us);
    put_u16(&frame.extra[4], from_i16(odometry->vx_mm_s));
    put_u16(&frame.extra[6], from_i16(odometry->vy_mm_s));
    put_u16(&frame.extra[8], from_i16(odometry->wz_mrad_s));
    put_u32(&frame.extra[10], from_i32(odometry->gz_urad_s));
    return clm_encode(&frame, out);
}

int clm_parse_odometry(const clm_frame_t *frame, clm_odometry_t *odometry)
{
    if (frame->command != CLM_CMD_ODOMETRY || frame->extra_len < CLM_ODOMETRY_PAYLOAD)
        return 0;
    odometry->seq = frame->seq;
    odometry->t_us = get_u32(&frame->extra[0]);
    odometry->vx_mm_s = to_i16(get_u16(&frame->extra[4]));
    odometry->vy_mm_s = to_i16(get_u16(&frame->extra[6]));
    odometry->wz_mrad_s = to_i16(get_u16(&frame->extra[8]));
    odometry->gz_urad_s = to_i32(get_u32(&frame->extra[10]));
    odometry->flags = frame->flags;
    return 1;
}

void clm_decoder_init(clm_decoder_t *decoder)
{
    memset(decoder, 0, sizeof *decoder);
}

size_t clm_decoder_buffered(const clm_decoder_t *decoder)
{
    return decoder->len;
}

static int known_command(uint8_t command)
{
    return command == CLM_CMD_SET_RPM || command == CLM_CMD_HOLD || command == CLM_CMD_HEARTBEAT
        || command == CLM_CMD_STATUS || command == CLM_CMD_ODOMETRY;
}

static void drop(clm_decoder_t *d, size_t n, int counted)
{
    memmove(d->buf, d->buf + n, d->len - n);
    d->len = (uint8_t)(d->len - n);
    if (counted)
        d->stats.discarded_bytes += (uint32_t)n;
}

/* Decides everything the buffered bytes allow; afterwards fewer than one full frame is held. */
static size_t process(clm_decoder_t *d, clm_frame_cb cb, void *ctx)
{
    size_t delivered = 0;
    for (;;) {
        size_t start = 0;
        while (start + 1 < d->len && !(d->buf[start] == CLM_SYNC0 && d->buf[start + 1] == CLM_SYNC1))
            start++;
        if (start + 1 >= d->len) {
            /* no sync: keep a trailing SYNC0, its SYNC1 may be the next byte */
            size_t keep = (d->len && d->buf[d->len - 1] == CLM_SYNC0) ? 1u : 0u;
            drop(d, d->len - keep, 1);
            return delivered;
        }
        if (start)
            drop(d, start, 1);
        if (d->len < 3)
            return delivered;
        uint8_t length = d->buf[2];
        if (length < CLM_BODY_V1 || length > CLM_MAX_BODY) {
            d->stats.bad_length++;
            drop(d, 1, 1);
            continue;
        }
        size_t total = 3u + length + 2u;
        if (d->len < total)
            return delivered;
        if (clm_crc16(&d->buf[2], 1u + length, 0xFFFFu) != get_u16(&d->buf[3 + length])) {
            d->stats.crc_errors++;
            drop(d, 1, 1);
            continue;
        }
        clm_frame_t frame;
        frame.seq = get_u16(&d->buf[3]);
        frame.command = d->buf[5];
        frame.rpm = get_u16(&d->buf[6]);
        frame.flags = d->buf[8];
        frame.reason = d->buf[9];
        frame.extra_len = (uint8_t)(length - CLM_BODY_V1);
        memcpy(frame.extra, &d->buf[10], frame.extra_len);
        drop(d, total, 0);
        if (!known_command(frame.command)) {
            d->stats.unknown_command++;
            continue;
        }
        d->stats.frames++;
        delivered++;
        if (cb)
            cb(&frame, ctx);
    }
}

size_t clm_decoder_feed(clm_decoder_t *decoder, const uint8_t *data, size_t n, clm_frame_cb cb, void *ctx)
{
    size_t delivered = 0;
    for (size_t i = 0; i < n; i++) {
        /* process() leaves at most CLM_MAX_FRAME - 1 bytes, so there is always room for one more */
        decoder->buf[decoder->len++] = data[i];
        delivered += process(decoder, cb, ctx);
    }
    return delivered;
}

/*
 * courtloc_mcu: the MCU side of the shooter bridge's serial frame (C99, no allocation, no libc beyond
 * <string.h>). The byte table is in docs/shooter.md ("MCU protocol"); the Python twin is
 * services/shooter_bridge/protocol.py and tests/test_firmware.py checks both agree byte for byte.
 *
 *   offset size field
 *   0      1    SYNC0 0xA5
 *   1      1    SYNC1 0x5A
 *   2      1    LEN   body bytes (7 in version 1; 7..32 accepted, extra body bytes ignored)
 *   3      2    SEQ   uint16 LE
 *   5      1    CMD
 *   6      2    RPM   uint16 LE
 *   8      1    FLAGS
 *   9      1    REASON
 *   10     LEN-7 extra body bytes (the ODOMETRY payload below; other commands: none)
 *   3+LEN  2    CRC   CRC-16/CCITT-FALSE over bytes 2 .. 2+LEN, little-endian
 *
 * ODOMETRY (0x82, MCU -> bridge): LEN 21, RPM 0, FLAGS = CLM_ODOM_*, REASON 0, then
 *   10 4 T_US uint32 MCU microseconds at the end of the window (wraps)   14 2 VX int16 mm/s forward
 *   16 2 VY int16 mm/s left   18 2 WZ int16 mrad/s from the wheels (CCW+)   20 4 GZ int32 urad/s gyro (CCW+)
 */
#ifndef COURTLOC_MCU_H
#define COURTLOC_MCU_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define CLM_SYNC0 0xA5u
#define CLM_SYNC1 0x5Au
#define CLM_BODY_V1 7u
#define CLM_MAX_BODY 32u
#define CLM_FRAME_V1_SIZE (3u + CLM_BODY_V1 + 2u)
#define CLM_MAX_FRAME (3u + CLM_MAX_BODY + 2u)
#define CLM_MAX_EXTRA (CLM_MAX_BODY - CLM_BODY_V1)
#define CLM_ODOMETRY_PAYLOAD 14u
#define CLM_ODOMETRY_FRAME_SIZE (CLM_FRAME_V1_SIZE + CLM_ODOMETRY_PAYLOAD)

/* Commands (CMD). */
#define CLM_CMD_SET_RPM 0x01u   /* bridge -> MCU: spin the wheels to RPM */
#define CLM_CMD_HOLD 0x02u      /* bridge -> MCU: do not shoot; REASON says why */
#define CLM_CMD_HEARTBEAT 0x03u /* bridge -> MCU: link alive; never extends a SET_RPM */
#define CLM_CMD_STATUS 0x81u    /* MCU -> bridge: RPM measured, SEQ last received, FLAGS status */
#define CLM_CMD_ODOMETRY 0x82u  /* MCU -> bridge: wheel odometry + gyro yaw rate in the extra bytes */

/* FLAGS, bridge -> MCU. */
#define CLM_FLAG_CLAMPED 0x01u
#define CLM_FLAG_SLEWING 0x02u
#define CLM_FLAG_BEYOND_TABLE 0x04u
#define CLM_FLAG_NO_YAW 0x08u

/* FLAGS, MCU -> bridge (STATUS). */
#define CLM_STATUS_AT_SPEED 0x01u
#define CLM_STATUS_HOLDING 0x02u
#define CLM_STATUS_WATCHDOG 0x04u
#define CLM_STATUS_FAULT 0x80u

/* FLAGS, MCU -> bridge (ODOMETRY). */
#define CLM_ODOM_WHEELS_VALID 0x01u
#define CLM_ODOM_GYRO_VALID 0x02u
#define CLM_ODOM_GYRO_SATURATED 0x04u
#define CLM_ODOM_WHEEL_SLIP 0x08u
#define CLM_ODOM_FAULT 0x80u

/* REASON codes of HOLD. */
#define CLM_REASON_NONE 0u
#define CLM_REASON_STALE 1u
#define CLM_REASON_INVALID 2u
#define CLM_REASON_OUTSIDE_AREA 3u
#define CLM_REASON_OUT_OF_RANGE 4u
#define CLM_REASON_NOT_FACING 5u
#define CLM_REASON_NO_POSE 6u
#define CLM_REASON_UNREACHABLE 7u
#define CLM_REASON_STOPPED 8u

typedef struct {
    uint16_t seq;
    uint8_t command;
    uint16_t rpm;
    uint8_t flags;
    uint8_t reason;
    uint8_t extra_len;                 /* body bytes after REASON (0 for the version-1 commands) */
    uint8_t extra[CLM_MAX_EXTRA];
} clm_frame_t;

/* One ODOMETRY window in the MCU's native fixed-point units. */
typedef struct {
    uint16_t seq;    /* counts ODOMETRY frames on their own */
    uint32_t t_us;   /* MCU clock at the end of the window */
    int16_t vx_mm_s;
    int16_t vy_mm_s;
    int16_t wz_mrad_s;
    int32_t gz_urad_s;
    uint8_t flags;   /* CLM_ODOM_* */
} clm_odometry_t;

typedef struct {
    uint32_t frames;          /* valid frames with a known command, handed to the callback */
    uint32_t crc_errors;      /* a sync and a plausible length, but the CRC did not match */
    uint32_t bad_length;      /* a sync followed by LEN outside 7..32 */
    uint32_t unknown_command; /* good CRC, CMD not known here: the frame is skipped */
    uint32_t discarded_bytes; /* bytes dropped while searching for a frame */
} clm_stats_t;

typedef struct {
    uint8_t buf[CLM_MAX_FRAME];
    uint8_t len;
    clm_stats_t stats;
} clm_decoder_t;

/* Called once per decoded frame, in stream order. */
typedef void (*clm_frame_cb)(const clm_frame_t *frame, void *ctx);

/* CRC-16/CCITT-FALSE (poly 0x1021, no reflection, no final xor); start with crc = 0xFFFF.
 * Incremental: clm_crc16(b, nb, clm_crc16(a, na, 0xFFFF)) == CRC of a then b. Check: "123456789" -> 0x29B1. */
uint16_t clm_crc16(const uint8_t *data, size_t n, uint16_t crc);

/* Writes the frame (12 bytes + extra_len) to out, which must have room for them; returns its size,
 * or 0 when extra_len exceeds CLM_MAX_EXTRA. */
size_t clm_encode(const clm_frame_t *frame, uint8_t *out);

/* Writes the 26-byte ODOMETRY frame; returns CLM_ODOMETRY_FRAME_SIZE. */
size_t clm_encode_odometry(const clm_odometry_t *odometry, uint8_t out[CLM_ODOMETRY_FRAME_SIZE]);

/* The odometry carried by a decoded ODOMETRY frame: 1 on success, 0 for another command or a short payload. */
int clm_parse_odometry(const clm_frame_t *frame, clm_odometry_t *odometry);

void clm_decoder_init(clm_decoder_t *decoder);

/* Feeds n received bytes (any chunking: one byte from a UART interrupt works); calls cb for every frame
 * completed. Resynchronises on noise, lost bytes and corrupt frames: on a bad LEN or CRC only the first
 * sync byte is dropped, so a real frame that starts inside a corrupt one is still found.
 * Returns the number of frames delivered by this call. */
size_t clm_decoder_feed(clm_decoder_t *decoder, const uint8_t *data, size_t n, clm_frame_cb cb, void *ctx);

/* Bytes held while waiting for the rest of a frame. */
size_t clm_decoder_buffered(const clm_decoder_t *decoder);

#ifdef __cplusplus
}
#endif

#endif /* COURTLOC_MCU_H */

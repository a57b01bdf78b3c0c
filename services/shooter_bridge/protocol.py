"""The binary frame between the bridge and the shooter MCU (see docs/shooter.md for the byte table).

    offset size field
    0      1    SYNC0 = 0xA5
    1      1    SYNC1 = 0x5A
    2      1    LEN   = number of BODY bytes (7 in version 1; receivers ignore extra trailing body bytes)
    3      2    SEQ   uint16, little-endian, +1 per frame sent, wraps
    5      1    CMD   command (Command)
    6      2    RPM   uint16, little-endian, wheel RPM (0 unless SET_RPM / STATUS)
    8      1    FLAGS bit field (Flag)
    9      1    REASON HoldReason for HOLD, else 0
    3+LEN  2    CRC   CRC-16/CCITT-FALSE over LEN..end of BODY (bytes 2 .. 2+LEN), little-endian

BODY is SEQ..REASON. All multi-byte fields are little-endian, CRC included.

ODOMETRY (MCU -> bridge, CMD 0x82) is the same frame with LEN = 21: the 7 bytes above (RPM = 0,
FLAGS = OdomFlag, REASON = 0) followed by the odometry payload (ODOMETRY_PAYLOAD):

    10     4    T_US  uint32, MCU clock in microseconds at the END of the window, free-running, wraps
    14     2    VX    int16, body-frame forward velocity, mm/s, mean over the window
    16     2    VY    int16, body-frame leftward velocity, mm/s
    18     2    WZ    int16, yaw rate from the wheels, mrad/s, counter-clockwise positive
    20     4    GZ    int32, yaw rate from the gyro, microrad/s, counter-clockwise positive

The window runs from the previous ODOMETRY frame's T_US to this one's; SEQ counts ODOMETRY frames
on their own (a gap is lost frames). A receiver that predates ODOMETRY skips it as an unknown command.
"""
from __future__ import annotations

import binascii
import enum
import struct
from dataclasses import dataclass

SYNC = b"\xa5\x5a"
BODY_V1 = struct.Struct("<HBHBB")  # seq, cmd, rpm, flags, reason
MAX_BODY = 32  # a larger LEN is garbage: resync instead of waiting for bytes that never come
FRAME_V1_SIZE = len(SYNC) + 1 + BODY_V1.size + 2
ODOMETRY_PAYLOAD = struct.Struct("<Ihhhi")  # t_us, vx, vy, wz, gz
ODOMETRY_FRAME_SIZE = FRAME_V1_SIZE + ODOMETRY_PAYLOAD.size


class Command(enum.IntEnum):
    SET_RPM = 0x01  # spin the wheels to RPM; a shot may be taken once the MCU reports it is at speed
    HOLD = 0x02  # do not shoot: feeder locked, wheels back to the MCU's idle speed; RPM is 0
    HEARTBEAT = 0x03  # the bridge is alive but has nothing new; it never extends a SET_RPM's lifetime
    STATUS = 0x81  # MCU -> bridge: RPM = measured wheel RPM, SEQ = last SEQ received, FLAGS = StatusFlag
    ODOMETRY = 0x82  # MCU -> bridge: wheel odometry and gyro yaw rate in the extra body bytes, FLAGS = OdomFlag


class Flag(enum.IntFlag):
    """Bridge -> MCU flags."""

    CLAMPED = 0x01  # RPM was clamped at the configured min/max
    SLEWING = 0x02  # RPM is still ramping towards the target (do not shoot yet)
    BEYOND_TABLE = 0x04  # distance outside the calibration table: RPM is the nearest end row's
    NO_YAW = 0x08  # the pose had no yaw: the bearing is unknown


class StatusFlag(enum.IntFlag):
    """MCU -> bridge flags (STATUS frames)."""

    AT_SPEED = 0x01
    HOLDING = 0x02
    WATCHDOG = 0x04  # the MCU went to HOLD on its own (no fresh command in time)
    FAULT = 0x80


class OdomFlag(enum.IntFlag):
    """MCU -> bridge flags (ODOMETRY frames)."""

    WHEELS_VALID = 0x01  # VX, VY, WZ are measurements (clear: encoder fault or not fitted)
    GYRO_VALID = 0x02  # GZ is a measurement (clear: no gyro, or not yet calibrated)
    GYRO_SATURATED = 0x04  # the gyro hit its full scale during the window: GZ is a lower bound
    WHEEL_SLIP = 0x08  # the MCU's own traction check tripped in the window (wheel speeds disagree)
    FAULT = 0x80


class HoldReason(enum.IntEnum):
    NONE = 0
    STALE = 1
    INVALID = 2
    OUTSIDE_AREA = 3
    OUT_OF_RANGE = 4
    NOT_FACING = 5
    NO_POSE = 6
    UNREACHABLE = 7
    STOPPED = 8  # the bridge is shutting down

    @classmethod
    def from_text(cls, reason: str) -> "HoldReason":
        try:
            return cls[reason.upper()]
        except KeyError:
            return cls.INVALID


def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final xor (check 0x29B1).

    The standard library's CRC-CCITT (XMODEM's routine) with the 0xFFFF start value is exactly this CRC.
    """
    return binascii.crc_hqx(data, crc)


@dataclass(frozen=True)
class McuFrame:
    seq: int
    command: Command
    rpm: int = 0
    flags: int = 0
    reason: int = 0
    extra: bytes = b""  # BODY bytes after REASON (the ODOMETRY payload; ignored by older receivers)


class FrameError(ValueError):
    pass


def encode(frame: McuFrame) -> bytes:
    if not 0 <= frame.rpm <= 0xFFFF:
        raise FrameError(f"rpm {frame.rpm} does not fit uint16")
    if BODY_V1.size + len(frame.extra) > MAX_BODY:
        raise FrameError(f"body of {BODY_V1.size + len(frame.extra)} bytes exceeds {MAX_BODY}")
    body = BODY_V1.pack(frame.seq & 0xFFFF, int(frame.command), frame.rpm, frame.flags & 0xFF,
                        frame.reason & 0xFF) + bytes(frame.extra)
    covered = bytes([len(body)]) + body
    return SYNC + covered + struct.pack("<H", crc16_ccitt_false(covered))


def decode(data: bytes) -> McuFrame:
    """Exactly one frame; raises FrameError when it is not one."""
    decoder = StreamDecoder()
    frames = decoder.feed(data)
    if len(frames) != 1 or decoder.buffered:
        raise FrameError(f"not exactly one valid frame ({len(frames)} decoded, stats {decoder.stats})")
    return frames[0]


@dataclass
class DecoderStats:
    frames: int = 0
    crc_errors: int = 0
    bad_length: int = 0
    unknown_command: int = 0
    discarded_bytes: int = 0


class StreamDecoder:
    """Frames out of a byte stream that may start mid-frame, lose bytes or carry noise.

    On a bad length or CRC only the first sync byte is dropped and the search restarts, so a real
    frame hidden inside a corrupt one is still found.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.stats = DecoderStats()

    @property
    def buffered(self) -> int:
        return len(self._buffer)

    def _discard(self, n: int) -> None:
        del self._buffer[:n]
        self.stats.discarded_bytes += n

    def feed(self, data: bytes | bytearray) -> list[McuFrame]:
        self._buffer.extend(data)
        frames: list[McuFrame] = []
        while True:
            start = self._buffer.find(SYNC)
            if start < 0:
                # keep a trailing SYNC0: its SYNC1 may be in the next chunk
                keep = 1 if self._buffer.endswith(SYNC[:1]) else 0
                self._discard(len(self._buffer) - keep)
                return frames
            if start:
                self._discard(start)
            if len(self._buffer) < 3:
                return frames
            length = self._buffer[2]
            if not BODY_V1.size <= length <= MAX_BODY:
                self.stats.bad_length += 1
                self._discard(1)
                continue
            total = 3 + length + 2
            if len(self._buffer) < total:
                return frames
            covered = bytes(self._buffer[2:3 + length])
            (crc,) = struct.unpack_from("<H", self._buffer, 3 + length)
            if crc16_ccitt_false(covered) != crc:
                self.stats.crc_errors += 1
                self._discard(1)
                continue
            seq, cmd, rpm, flags, reason = BODY_V1.unpack_from(covered, 1)
            extra = covered[1 + BODY_V1.size:]
            del self._buffer[:total]
            try:
                command = Command(cmd)
            except ValueError:
                self.stats.unknown_command += 1
                continue
            self.stats.frames += 1
            frames.append(McuFrame(seq=seq, command=command, rpm=rpm, flags=flags, reason=reason, extra=extra))


@dataclass(frozen=True)
class OdometrySample:
    """One ODOMETRY frame in SI units (body frame: x forward, y left, yaw counter-clockwise)."""

    seq: int
    mcu_time_us: int  # uint32, wraps: unwrap it against the previous sample, never compare raw values
    vx_m_s: float
    vy_m_s: float
    wz_wheels_rad_s: float
    wz_gyro_rad_s: float
    flags: OdomFlag

    @property
    def wheels_valid(self) -> bool:
        return bool(self.flags & OdomFlag.WHEELS_VALID)

    @property
    def gyro_valid(self) -> bool:
        return bool(self.flags & OdomFlag.GYRO_VALID)


def _fixed(value: float, scale: float, bits: int, name: str) -> int:
    raw = int(round(value * scale))
    limit = 1 << (bits - 1)
    if not -limit <= raw < limit:
        raise FrameError(f"{name} {value} does not fit int{bits} at {1 / scale:g} per count")
    return raw


def encode_odometry(sample: OdometrySample) -> bytes:
    """The ODOMETRY frame the MCU sends (used by the tests and the twin's MCU stand-in)."""
    payload = ODOMETRY_PAYLOAD.pack(
        sample.mcu_time_us & 0xFFFFFFFF,
        _fixed(sample.vx_m_s, 1e3, 16, "vx_m_s"), _fixed(sample.vy_m_s, 1e3, 16, "vy_m_s"),
        _fixed(sample.wz_wheels_rad_s, 1e3, 16, "wz_wheels_rad_s"),
        _fixed(sample.wz_gyro_rad_s, 1e6, 32, "wz_gyro_rad_s"))
    return encode(McuFrame(seq=sample.seq, command=Command.ODOMETRY, flags=int(sample.flags) & 0xFF,
                           extra=payload))


def parse_odometry(frame: McuFrame) -> OdometrySample:
    """The odometry carried by an ODOMETRY frame; FrameError when it is another command or too short."""
    if frame.command is not Command.ODOMETRY:
        raise FrameError(f"{frame.command.name} is not an ODOMETRY frame")
    if len(frame.extra) < ODOMETRY_PAYLOAD.size:
        raise FrameError(f"ODOMETRY payload of {len(frame.extra)} bytes, {ODOMETRY_PAYLOAD.size} needed")
    t_us, vx, vy, wz, gz = ODOMETRY_PAYLOAD.unpack_from(frame.extra)
    return OdometrySample(seq=frame.seq, mcu_time_us=t_us, vx_m_s=vx / 1e3, vy_m_s=vy / 1e3,
                          wz_wheels_rad_s=wz / 1e3, wz_gyro_rad_s=gz / 1e6, flags=OdomFlag(frame.flags))

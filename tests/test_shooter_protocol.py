"""The MCU frame: CRC, byte layout, corruption and resynchronisation."""
from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest

from courtloc.services.shooter_bridge.protocol import (
    FRAME_V1_SIZE, ODOMETRY_FRAME_SIZE, Command, FrameError, McuFrame, OdometrySample, OdomFlag, StreamDecoder,
    crc16_ccitt_false, decode, encode, encode_odometry, parse_odometry)


def test_crc_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1  # the catalogue check value of CRC-16/CCITT-FALSE
    assert crc16_ccitt_false(b"") == 0xFFFF
    assert crc16_ccitt_false(b"56789", crc16_ccitt_false(b"1234")) == 0x29B1  # incremental use


def test_byte_layout_matches_the_documented_table() -> None:
    data = encode(McuFrame(seq=0x1234, command=Command.SET_RPM, rpm=2500, flags=0x03, reason=0))
    assert len(data) == FRAME_V1_SIZE == 12
    assert data[:10] == bytes([0xA5, 0x5A, 0x07, 0x34, 0x12, 0x01, 0xC4, 0x09, 0x03, 0x00])
    assert struct.unpack("<H", data[10:])[0] == crc16_ccitt_false(data[2:10])


@pytest.mark.parametrize("command", list(Command))
def test_round_trip(command: Command) -> None:
    frame = McuFrame(seq=65535, command=command, rpm=4321, flags=0x0F, reason=3)
    assert decode(encode(frame)) == frame


def test_rpm_out_of_range_is_refused() -> None:
    with pytest.raises(FrameError):
        encode(McuFrame(seq=0, command=Command.SET_RPM, rpm=70000))


def test_every_single_bit_error_is_detected() -> None:
    data = encode(McuFrame(seq=7, command=Command.SET_RPM, rpm=3000, flags=1))
    for index in range(len(data)):
        for bit in range(8):
            corrupt = bytearray(data)
            corrupt[index] ^= 1 << bit
            decoder = StreamDecoder()
            assert decoder.feed(bytes(corrupt)) == [], (index, bit)
    decoder = StreamDecoder()
    corrupt = bytearray(data)
    corrupt[7] ^= 0x10  # inside RPM
    assert decoder.feed(bytes(corrupt)) == []
    assert decoder.stats.crc_errors == 1


def test_resync_after_garbage_in_random_chunks() -> None:
    rng = random.Random(7)
    frames = [McuFrame(seq=i, command=Command.SET_RPM, rpm=1000 + i, flags=i & 3) for i in range(20)]
    stream = bytearray()
    for frame in frames:
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 30)))
        stream += b"\xa5\x5a\xff" + b"\xa5\x5a\x07\x01"  # a sync with an impossible length, a truncated frame
        stream += encode(frame)
    stream += b"\xa5"  # a dangling sync byte at the end stays buffered, not lost
    decoder = StreamDecoder()
    got: list[McuFrame] = []
    position = 0
    while position < len(stream):
        size = rng.randrange(1, 17)
        got += decoder.feed(bytes(stream[position:position + size]))
        position += size
    assert got == frames
    assert decoder.stats.bad_length >= 20
    assert decoder.buffered == 1


def test_longer_body_from_newer_firmware_is_accepted() -> None:
    body = struct.pack("<HBHBB", 9, int(Command.STATUS), 2999, 0x01, 0) + b"\x11\x22"  # two extra bytes
    covered = bytes([len(body)]) + body
    data = b"\xa5\x5a" + covered + struct.pack("<H", crc16_ccitt_false(covered))
    assert decode(data) == McuFrame(seq=9, command=Command.STATUS, rpm=2999, flags=0x01, reason=0, extra=b"\x11\x22")


def test_unknown_command_is_counted_and_skipped() -> None:
    body = struct.pack("<HBHBB", 1, 0x42, 0, 0, 0)
    covered = bytes([len(body)]) + body
    data = b"\xa5\x5a" + covered + struct.pack("<H", crc16_ccitt_false(covered))
    decoder = StreamDecoder()
    good = encode(McuFrame(seq=2, command=Command.HOLD, reason=1))
    assert decoder.feed(data + good) == [decode(good)]
    assert decoder.stats.unknown_command == 1


@pytest.mark.parametrize("frame, hex_bytes", [
    (McuFrame(seq=0x1234, command=Command.SET_RPM, rpm=2500, flags=0x03), "a5 5a 07 34 12 01 c4 09 03 00 6f e7"),
    (McuFrame(seq=0x0001, command=Command.HOLD, reason=1), "a5 5a 07 01 00 02 00 00 00 01 e5 1a"),
    (McuFrame(seq=0x0002, command=Command.HEARTBEAT), "a5 5a 07 02 00 03 00 00 00 00 17 78"),
    (McuFrame(seq=0x0010, command=Command.STATUS, rpm=2480, flags=0x01), "a5 5a 07 10 00 81 b0 09 01 00 ad 15"),
])
def test_documented_vectors(frame: McuFrame, hex_bytes: str) -> None:
    """The example frames in docs/shooter.md, which the firmware team tests against."""
    data = bytes.fromhex(hex_bytes)
    assert encode(frame) == data
    assert decode(data) == frame
    assert hex_bytes in (Path(__file__).resolve().parents[1] / "docs" / "shooter.md").read_text()


# ---- ODOMETRY (MCU -> bridge) -------------------------------------------------------------------
ODOMETRY_VECTORS = [  # the documented examples in docs/shooter.md, byte for byte
    (OdometrySample(seq=0x0102, mcu_time_us=123456789, vx_m_s=1.5, vy_m_s=-0.25, wz_wheels_rad_s=0.5,
                    wz_gyro_rad_s=0.498765, flags=OdomFlag.WHEELS_VALID | OdomFlag.GYRO_VALID),
     "a5 5a 15 02 01 82 00 00 03 00 15 cd 5b 07 dc 05 06 ff f4 01 4d 9c 07 00 ea c0"),
    (OdometrySample(seq=0xFFFF, mcu_time_us=0xFFFFFFF0, vx_m_s=-0.001, vy_m_s=0.0, wz_wheels_rad_s=-3.2,
                    wz_gyro_rad_s=-34.906585, flags=OdomFlag(0x0F)),
     "a5 5a 15 ff ff 82 00 00 0f 00 f0 ff ff ff ff ff 00 00 80 f3 27 5e eb fd 4b 1b"),
    (OdometrySample(seq=7, mcu_time_us=10000, vx_m_s=0.0, vy_m_s=0.0, wz_wheels_rad_s=0.0, wz_gyro_rad_s=0.0,
                    flags=OdomFlag(0)),
     "a5 5a 15 07 00 82 00 00 00 00 10 27 00 00 00 00 00 00 00 00 00 00 00 00 aa fe"),
]


@pytest.mark.parametrize("sample,hexbytes", ODOMETRY_VECTORS)
def test_odometry_test_vectors(sample: OdometrySample, hexbytes: str) -> None:
    data = encode_odometry(sample)
    assert data == bytes.fromhex(hexbytes)
    assert len(data) == ODOMETRY_FRAME_SIZE == 26
    assert parse_odometry(decode(data)) == sample
    assert struct.unpack("<H", data[-2:])[0] == crc16_ccitt_false(data[2:-2])


def test_odometry_byte_layout() -> None:
    data = encode_odometry(ODOMETRY_VECTORS[0][0])
    assert data[2] == 21 and data[5] == 0x82
    t_us, vx, vy, wz, gz = struct.unpack_from("<Ihhhi", data, 10)
    assert (t_us, vx, vy, wz, gz) == (123456789, 1500, -250, 500, 498765)


def test_odometry_out_of_range_is_refused() -> None:
    too_fast = OdometrySample(seq=0, mcu_time_us=0, vx_m_s=40.0, vy_m_s=0.0, wz_wheels_rad_s=0.0,
                              wz_gyro_rad_s=0.0, flags=OdomFlag.WHEELS_VALID)
    with pytest.raises(FrameError, match="vx_m_s"):
        encode_odometry(too_fast)


def test_a_short_odometry_payload_is_refused() -> None:
    short = decode(encode(McuFrame(seq=1, command=Command.ODOMETRY, extra=b"\x00" * 5)))
    with pytest.raises(FrameError, match="payload"):
        parse_odometry(short)
    with pytest.raises(FrameError, match="not an ODOMETRY"):
        parse_odometry(McuFrame(seq=1, command=Command.STATUS))


def test_odometry_frames_interleaved_with_status_in_a_noisy_stream() -> None:
    rng = random.Random(11)
    sent = [OdometrySample(seq=i, mcu_time_us=1_000_000 + 10_000 * i, vx_m_s=(10 * i) / 1e3, vy_m_s=0.0,
                           wz_wheels_rad_s=(-2 * i) / 1e3, wz_gyro_rad_s=(-2000 * i) / 1e6, flags=OdomFlag(3))
            for i in range(30)]
    stream = bytearray()
    for sample in sent:
        stream += bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        stream += encode(McuFrame(seq=sample.seq, command=Command.STATUS, rpm=2000))
        stream += encode_odometry(sample)
    decoder = StreamDecoder()
    got = []
    while stream:
        n = rng.randrange(1, 20)
        got += decoder.feed(bytes(stream[:n]))
        del stream[:n]
    odometry = [parse_odometry(f) for f in got if f.command is Command.ODOMETRY]
    assert odometry == sent
    assert sum(f.command is Command.STATUS for f in got) == len(sent)

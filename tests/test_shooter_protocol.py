"""The MCU frame: CRC, byte layout, corruption and resynchronisation."""
from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
from courtloc.services.shooter_bridge.protocol import (
    FRAME_V1_SIZE,
    Command,
    FrameError,
    McuFrame,
    StreamDecoder,
    crc16_ccitt_false,
    decode,
    encode,
)


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
    assert decode(data) == McuFrame(seq=9, command=Command.STATUS, rpm=2999, flags=0x01, reason=0)


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

"""A JPEG's declared size, read from its header without decoding a pixel.

A few hundred bytes can declare a 16000x16000 image; the decoder would allocate it before anyone
checks. Reading the frame header (SOFn) first lets a stage refuse it at no cost.
"""
from __future__ import annotations

import struct

SOI = b"\xff\xd8"
# Start-of-frame markers carry the size: every SOFn except DHT (C4), JPG (C8) and DAC (CC).
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_STANDALONE = {0x01, *range(0xD0, 0xD8)}  # TEM, RSTn: no length field
_SOS = 0xDA  # entropy-coded data follows: no size before it means no usable frame


class NotJpeg(ValueError):
    """The bytes are not a JPEG, or its header ends before it says how big the image is."""


def jpeg_size(data: bytes | memoryview) -> tuple[int, int]:
    """(width, height) declared by the JPEG in `data` (bytes, or a view of a received buffer); NotJpeg if it
    is not one."""
    if bytes(data[:len(SOI)]) != SOI:
        raise NotJpeg("no JPEG start-of-image marker")
    pos = 2
    n = len(data)
    while pos + 1 < n:
        if data[pos] != 0xFF:
            raise NotJpeg(f"expected a marker at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
            continue
        pos += 2
        if marker in _STANDALONE:
            continue
        if marker == _SOS or marker == 0xD9:
            break
        if pos + 2 > n:
            break
        (length,) = struct.unpack(">H", data[pos:pos + 2])
        if length < 2:
            raise NotJpeg(f"segment length {length} at byte {pos}")
        if marker in _SOF:
            if pos + 7 > n:
                break
            height, width = struct.unpack(">HH", data[pos + 3:pos + 7])
            return width, height
        pos += length
    raise NotJpeg("no frame header (SOF) before the image data")

"""Camera frames in zenoh shared memory: written once by the publisher, copied out once by the reader.

The bytes are exactly `codec.encode(Frame)` (the msgpack map, `data` last), so every subscriber
(monitor, recorder, a stage on another host) decodes them as before; only how they travel changes.
The publisher writes the map's prefix and the pixels into a buffer of its own zenoh `ShmProvider`;
zenoh hands that buffer to a session on the same host as a descriptor and sends it as bytes over any
link that cannot share memory (the pit laptop over Wi-Fi), with no choice left to the caller.

Bounded: the provider is a fixed pool, allocation never blocks, and a publish that finds the pool
full (subscribers still holding old frames) goes out as plain bytes and is counted.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np
import zenoh
from zenoh.shm import GarbageCollect, JustAlloc, ShmProvider

from courtloc.common import codec
from courtloc.common.messages import Frame, Header

_BIN_TAGS = {0xC4: 1, 0xC5: 2, 0xC6: 4}  # msgpack bin8/16/32 -> bytes of the length that follow


def _bin_header(length: int) -> bytes:
    if length < 1 << 8:
        return b"\xc4" + length.to_bytes(1, "big")
    if length < 1 << 16:
        return b"\xc5" + length.to_bytes(2, "big")
    return b"\xc6" + length.to_bytes(4, "big")


def frame_prefix(meta: Frame, data_len: int) -> bytes:
    """The bytes of `codec.encode(meta with data of data_len bytes)` that come before the data."""
    fields = meta.model_dump(exclude={"data"})
    packer = msgpack.Packer(use_bin_type=True)
    parts = [packer.pack_map_header(len(fields) + 1)]
    for key, value in fields.items():
        parts += [packer.pack(key), packer.pack(value)]
    parts += [packer.pack("data"), _bin_header(data_len)]
    return b"".join(parts)


class PixelStaging:
    """A reused bytes-like image buffer: zenoh-python writes provider buffers from bytes/bytearray only,
    so pixels land here first (no allocation per frame; a device or video source decodes straight into
    `view`) and then once in shared memory."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.view: np.ndarray = np.empty(0, np.uint8)

    def fill(self, image: np.ndarray) -> bytearray:
        if image is self.view:  # the source decoded straight into this buffer
            return self._buffer
        if self.view.shape != image.shape:
            self._buffer = bytearray(image.nbytes)
            self.view = np.frombuffer(self._buffer, np.uint8).reshape(image.shape)
        np.copyto(self.view, image)
        return self._buffer


@dataclass
class ShmStats:
    in_shm: int = 0
    fallback_bytes: int = 0  # pool exhausted (or shared memory off): sent as plain bytes


class ShmFramePublisher:
    """Publishes frames through a fixed shared-memory pool; never blocks on a full pool."""

    def __init__(self, publisher: zenoh.Publisher, pool_bytes: int, enabled: bool = True) -> None:
        self._publisher = publisher
        self._provider = ShmProvider.default_backend(pool_bytes) if enabled else None
        # Collect buffers subscribers have released, then give up at once: BlockOn would hang the stage
        # for as long as a consumer holds frames.
        self._policy = GarbageCollect(JustAlloc())
        self.stats = ShmStats()

    @property
    def enabled(self) -> bool:
        return self._provider is not None

    def put(self, meta: Frame, data: bytes | bytearray) -> bool:
        """Publish `meta` (its own `data` ignored) carrying `data` as the frame bytes; False if sent as bytes."""
        prefix = frame_prefix(meta, len(data))
        if self._provider is not None:
            try:
                buffer = self._provider.alloc(len(prefix) + len(data), self._policy)
            except zenoh.ZError:
                buffer = None
            if buffer is not None:
                buffer[0:len(prefix)] = prefix
                buffer[len(prefix):len(prefix) + len(data)] = data
                self._publisher.put(zenoh.ZBytes(buffer))
                self.stats.in_shm += 1
                return True
        self.stats.fallback_bytes += 1
        self._publisher.put(prefix + data)
        return False


@dataclass
class ReceivedFrame:
    """A decoded frame whose pixels are a view into the one copy taken out of the payload."""

    message: Frame  # header and geometry; its `data` is empty
    pixels: memoryview
    via_shm: bool

    @property
    def header(self) -> Header:
        return self.message.header


def _split(raw: bytes) -> tuple[bytes, memoryview] | None:
    """The frame map with an empty `data`, and the data in place; None unless `data` is the last field."""
    try:
        unpacker = msgpack.Unpacker(io.BytesIO(raw), raw=False, strict_map_key=True, read_size=1024)
        n_fields = unpacker.read_map_header()
        for index in range(n_fields):
            if unpacker.unpack() == "data":
                break
            unpacker.skip()
        else:
            return None
        if index != n_fields - 1:
            return None
        at = unpacker.tell()
    except Exception:  # noqa: BLE001 - anything msgpack dislikes goes through the codec, which names the reason
        return None
    size_len = _BIN_TAGS.get(raw[at]) if at < len(raw) else None
    if size_len is None:
        return None
    start = at + 1 + size_len
    if start + int.from_bytes(raw[at + 1:start], "big") != len(raw):
        return None
    return raw[:at] + b"\xc4\x00", memoryview(raw)[start:]


def decode_frame_payload(payload: Any) -> ReceivedFrame:
    """A camera/frame payload (zenoh.ZBytes or bytes) -> header + pixels, copying the pixels once.

    Raises codec.DecodeError like `codec.decode`.
    """
    shm = payload.as_shm() if isinstance(payload, zenoh.ZBytes) else None
    raw = bytes(shm) if shm is not None else bytes(payload)  # the one copy; the buffer can go back now
    parts = _split(raw)
    if parts is None:
        message = codec.decode(raw, Frame)
        return ReceivedFrame(message.model_copy(update={"data": b""}), memoryview(message.data), shm is not None)
    head, pixels = parts
    return ReceivedFrame(codec.decode(head, Frame), pixels, shm is not None)

"""Codecs of the wire payloads the message contract carries as bytes: camera pixels, scan hits, colour marks.

Every stage and tool that reads a `Frame` or an `Edges` payload goes through here, so the byte layout
is written down once. Bad input raises `FrameError`, whose `reason` is a short stable word a service
counts ("dtype", "shape", "channels", "size", "empty", "undecodable", "encoding", "not_jpeg").
"""
from __future__ import annotations

import cv2
import numpy as np

from courtloc.common.jpeg_header import NotJpeg, jpeg_size
from courtloc.common.messages import Edges, Frame

# A hit is (row, col, ray, d); int16 bounds every frame we accept (checked where hits are made).
HIT_DTYPE = np.int16
_HIT_WIRE_DTYPE = "<i2"
_HIT_FIELDS = 4
MARK_FIELDS = 3  # a colour mark is (row, col, mark index into the court's marks)


class FrameError(ValueError):
    """A frame a stage cannot use; `reason` is one stable word for counters, the message says why."""

    def __init__(self, message: str, reason: str = "bad_frame") -> None:
        super().__init__(message)
        self.reason = reason


def check_bgr(bgr: object, width: int | None = None, height: int | None = None) -> np.ndarray:
    """`bgr` if it is a (H, W, 3) uint8 array of the expected size (None: any size), else FrameError."""
    if not isinstance(bgr, np.ndarray):
        raise FrameError(f"expected a numpy array, got {type(bgr).__name__}", reason="type")
    if bgr.dtype != np.uint8:
        raise FrameError(f"expected uint8 pixels, got {bgr.dtype}", reason="dtype")
    if bgr.ndim != 3:
        raise FrameError(f"expected (height, width, 3), got shape {bgr.shape}", reason="shape")
    if bgr.shape[2] != 3:
        raise FrameError(f"expected 3 channels (BGR), got {bgr.shape[2]}", reason="channels")
    if bgr.shape[0] == 0 or bgr.shape[1] == 0:
        raise FrameError(f"frame has no pixels, shape {bgr.shape}", reason="empty")
    if (width is not None and bgr.shape[1] != width) or (height is not None and bgr.shape[0] != height):
        raise FrameError(f"expected {width}x{height}, got {bgr.shape[1]}x{bgr.shape[0]}", reason="size")
    return bgr


def decode_frame(encoding: str, data: bytes, width: int, height: int) -> np.ndarray:
    """A camera message's payload -> (H, W, 3) uint8 BGR, checked against the declared size."""
    if not data:
        raise FrameError("frame payload is empty", reason="empty")
    if encoding == "jpeg":
        # The declared size is checked before decoding: a tiny file may declare a huge image, and
        # OpenCV would decode any format it knows (PNG, BMP...) under the name "jpeg".
        try:
            declared = jpeg_size(data)
        except NotJpeg as exc:
            raise FrameError(f"encoding 'jpeg' but {len(data)} bytes are not a JPEG: {exc}", reason="not_jpeg") from None
        if declared != (width, height):
            raise FrameError(f"the JPEG declares {declared[0]}x{declared[1]}, the message {width}x{height}",
                             reason="size")
        bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FrameError(f"{len(data)} bytes are not a decodable image", reason="undecodable")
    elif encoding == "bgr8":
        expected = width * height * 3
        if len(data) != expected:
            raise FrameError(f"bgr8 payload of {len(data)} bytes, {width}x{height}x3 needs {expected}",
                             reason="size")
        bgr = np.frombuffer(data, np.uint8).reshape(height, width, 3)
    else:
        raise FrameError(f"unknown encoding {encoding!r} (expected 'jpeg' or 'bgr8')", reason="encoding")
    return check_bgr(bgr, width, height)


def frame_pixels(frame: Frame) -> np.ndarray:
    """The BGR pixels of a Frame message (FrameError when its bytes do not make one)."""
    return decode_frame(frame.encoding, frame.data, frame.width, frame.height)


def hits_to_bytes(hits: np.ndarray) -> bytes:
    """Hits as the Edges message carries them: int16 little-endian, row-major (N x 4)."""
    return np.ascontiguousarray(hits, dtype=_HIT_WIRE_DTYPE).tobytes()


def _rows_from_bytes(data: bytes, fields: int, what: str) -> np.ndarray:
    row_bytes = fields * np.dtype(_HIT_WIRE_DTYPE).itemsize
    if len(data) % row_bytes:
        raise ValueError(f"{len(data)} bytes is not a whole number of {row_bytes}-byte {what}")
    return np.frombuffer(data, _HIT_WIRE_DTYPE).reshape(-1, fields).astype(HIT_DTYPE)


def hits_from_bytes(data: bytes) -> np.ndarray:
    """Inverse of `hits_to_bytes`; ValueError if the length is not a whole number of hits."""
    return _rows_from_bytes(data, _HIT_FIELDS, "hits")


def edges_hits(edges: Edges) -> np.ndarray:
    """The hits of an Edges message; ValueError when the payload disagrees with its `n_hits`."""
    hits = hits_from_bytes(edges.hits)
    if len(hits) != edges.n_hits:
        raise ValueError(f"{len(hits)} hits in the payload, the header says {edges.n_hits}")
    return hits


def marks_to_bytes(marks: np.ndarray) -> bytes:
    """Colour marks as the Edges message carries them: int16 little-endian (M x 3: row, col, mark index)."""
    return np.ascontiguousarray(marks, dtype=_HIT_WIRE_DTYPE).reshape(-1, MARK_FIELDS).tobytes()


def edges_marks(edges: Edges) -> np.ndarray:
    """The colour marks of an Edges message; ValueError when the payload disagrees with its `n_marks`."""
    marks = _rows_from_bytes(edges.marks, MARK_FIELDS, "marks")
    if len(marks) != edges.n_marks:
        raise ValueError(f"{len(marks)} marks in the payload, the header says {edges.n_marks}")
    return marks

"""The preprocess stage as pure functions: frame in, hits (and the paper model's input) out.

The Zenoh service wraps `Preprocessor`; everything here is synchronous and needs no bus, so it can be
tested and benchmarked alone. Bad input raises `FrameError`, whose `reason` is a
short stable word the service can count ("dtype", "shape", "channels", "size", "empty", "undecodable",
"encoding", "not_jpeg").
"""
from __future__ import annotations

import cv2
import numpy as np

from courtloc.common.jpeg_header import NotJpeg, jpeg_size
from courtloc.services.preprocess.config import PreprocessConfig
from courtloc.services.preprocess.hsv_mask import WhiteMask
from courtloc.services.preprocess.radial_scan import HIT_DTYPE, RadialScanner
from courtloc.services.preprocess.seed_dots import stamp_dots


class FrameError(ValueError):
    """A frame this stage cannot use; `reason` is one stable word for counters, the message says why."""

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


def read_image_file(path: str) -> np.ndarray:
    """An image file (any format OpenCV reads) -> BGR; FrameError if missing, empty or undecodable."""
    try:
        with open(path, "rb") as handle:
            data = handle.read()
    except OSError as exc:
        raise FrameError(f"{path}: {exc.strerror or exc}", reason="unreadable") from exc
    if not data:
        raise FrameError(f"{path} is empty", reason="empty")
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise FrameError(f"{path} is not a decodable image", reason="undecodable")
    return bgr


class Preprocessor:
    """Algorithm 1 for one configuration: BGR frame -> int16 (N, 4) hits (row, col, ray, d)."""

    def __init__(self, config: PreprocessConfig, native: bool | None = None) -> None:
        """native: the compiled scan when built (None), never (False) or required (True); same hits."""
        self.config = config
        self._white = WhiteMask(config.hsv_ranges)
        self._scanner = RadialScanner(config.scan, native=native)

    @property
    def native(self) -> bool:
        return self._scanner.native

    def warm_up(self) -> None:
        """Build the tables for the configured frame size now (a frame of unknown size builds its own later)."""
        width, height = self.config.frame_width, self.config.frame_height
        if width is not None and height is not None:
            self.process(np.zeros((height, width, 3), np.uint8))

    def check(self, bgr: object) -> np.ndarray:
        return check_bgr(bgr, self.config.frame_width, self.config.frame_height)

    def process(self, bgr: np.ndarray) -> np.ndarray:
        """Hits of one frame, ordered by ray then d; FrameError for a frame of the wrong kind."""
        return self._scanner.scan_bgr(self.check(bgr), self._white)

    def process_with_paper(self, bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(hits, paper_image) of one frame: everything the paper's pipeline produced, in one call."""
        hits = self.process(bgr)
        return hits, self.paper_image(hits, bgr.shape[0], bgr.shape[1])

    def mask(self, bgr: np.ndarray) -> np.ndarray:
        """The full-frame white mask (uint8 0/255), for the debug preview; the scan never needs it."""
        return self._white.frame(self.check(bgr))

    def paper_image(self, hits: np.ndarray, height: int, width: int) -> np.ndarray:
        """The paper model's input: the dot image of `hits` without the top `crop_top` rows, float32 0/1."""
        crop_top = self.config.crop_top
        if crop_top >= height:
            raise FrameError(f"crop_top={crop_top} leaves no rows of a {height}-row frame", reason="size")
        canvas = np.zeros((height - crop_top, width), np.float32)
        if len(hits):
            stamp_dots(canvas, hits[:, 0], hits[:, 1], self.config.dot_radius, 1.0, row_offset=crop_top)
        return canvas

    def debug_preview(self, bgr: np.ndarray, hits: np.ndarray) -> np.ndarray:
        """A BGR picture for humans: the mask in grey, the hits in red, the crop line in blue."""
        preview = cv2.cvtColor(self.mask(bgr) // 2, cv2.COLOR_GRAY2BGR)
        for row, col in hits[:, :2].astype(np.int64):
            cv2.circle(preview, (int(col), int(row)), 2, (0, 0, 255), thickness=-1)
        crop = self.config.crop_top
        if 0 < crop < preview.shape[0]:
            cv2.line(preview, (0, crop), (preview.shape[1] - 1, crop), (255, 0, 0), 1)
        return preview

    def debug_preview_jpeg(self, bgr: np.ndarray, hits: np.ndarray) -> bytes:
        ok, encoded = cv2.imencode(".jpg", self.debug_preview(bgr, hits),
                                   [cv2.IMWRITE_JPEG_QUALITY, self.config.debug_preview.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding of the debug preview failed")
        return encoded.tobytes()


def hits_to_bytes(hits: np.ndarray) -> bytes:
    """Hits as the Edges message carries them: int16 little-endian, row-major (N x 4)."""
    return np.ascontiguousarray(hits, dtype="<i2").tobytes()


def hits_from_bytes(data: bytes) -> np.ndarray:
    """Inverse of `hits_to_bytes`; ValueError if the length is not a whole number of hits."""
    if len(data) % 8:
        raise ValueError(f"{len(data)} bytes is not a whole number of 8-byte hits")
    return np.frombuffer(data, "<i2").reshape(-1, 4).astype(HIT_DTYPE)

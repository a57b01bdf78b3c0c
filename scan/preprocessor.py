"""The preprocess stage as pure functions: frame in, hits (and the paper model's input) out.

The Zenoh service wraps `Preprocessor`; everything here is synchronous and needs no bus, so it can be
tested and benchmarked alone. Bad input raises the contract's `FrameError`
(`courtloc.common.payloads`), whose `reason` the service counts.
"""
from __future__ import annotations

import cv2
import numpy as np

from courtloc.common.payloads import FrameError, check_bgr
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.hsv_mask import WhiteMask
from courtloc.scan.marks import MarkFinder
from courtloc.scan.radial_scan import RadialScanner
from courtloc.scan.seed_dots import stamp_dots


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
        self._marks = MarkFinder(config.marks, config.mark_grid_px, config.max_marks)

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

    def marks(self, bgr: np.ndarray) -> np.ndarray:
        """The colour marks of one frame (`scan.marks`): int16 (M, 3) rows (row, col, mark index)."""
        return self._marks.find(self.check(bgr))

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

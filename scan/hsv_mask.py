"""The white mask: BGR -> OpenCV HSV -> union of `cv2.inRange` boxes, as 0/255 uint8.

Three forms of the same per-pixel function: `WhiteMask.frame` on a whole frame (debug preview, reference),
`WhiteMask.pixels` on a list of gathered pixels (the numpy scan only looks at the pixels its rays visit), and
`WhiteMask.bit_table`, its value for every one of the 2^24 BGR colours, for the compiled scan. OpenCV's
BGR->HSV conversion is per pixel, so all three agree; the tests check it.
"""
from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from courtloc.scan.config import HsvRange


def _bounds(ranges: Sequence[HsvRange]) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(np.array(r.lower, np.uint8), np.array(r.upper, np.uint8)) for r in ranges]


def _mask_of_hsv(hsv: np.ndarray, bounds: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    mask = cv2.inRange(hsv, bounds[0][0], bounds[0][1])
    for lower, upper in bounds[1:]:
        cv2.bitwise_or(mask, cv2.inRange(hsv, lower, upper), dst=mask)
    return mask


class WhiteMask:
    """The mask function for one set of HSV ranges, with the bounds converted once."""

    def __init__(self, ranges: Sequence[HsvRange]) -> None:
        if not ranges:
            raise ValueError("at least one HSV range is needed")
        self._bounds = _bounds(ranges)
        self._bit_table: np.ndarray | None = None

    def frame(self, bgr: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 BGR -> (H, W) uint8 mask, 255 where white."""
        return _mask_of_hsv(cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV), self._bounds)

    def pixels(self, bgr_pixels: np.ndarray) -> np.ndarray:
        """(N, 3) uint8 BGR pixels -> (N,) uint8 mask values, 255 where white."""
        n = bgr_pixels.shape[0]
        if n == 0:
            return np.zeros(0, np.uint8)
        # A one-row image lets OpenCV convert the list exactly as it converts a frame.
        hsv = cv2.cvtColor(bgr_pixels.reshape(1, n, 3), cv2.COLOR_BGR2HSV)
        return _mask_of_hsv(hsv, self._bounds).reshape(n)

    def bit_table(self) -> np.ndarray:
        """The mask of every colour as 2 MiB of bits: colour (b, g, r) is bit k & 7 of byte k >> 3, k = b<<16 | g<<8 | r.

        Computed by OpenCV itself (one 256 x 256 image of all (g, r) per blue level), so a lookup in it is
        exactly `frame`. Built on first use (~0.1-0.2 s) and kept by this instance.
        """
        if self._bit_table is None:
            image = np.empty((256, 256, 3), np.uint8)
            image[..., 1] = np.arange(256, dtype=np.uint8)[:, None]
            image[..., 2] = np.arange(256, dtype=np.uint8)[None, :]
            table = np.empty((256, 256 * 256 // 8), np.uint8)
            for blue in range(256):
                image[..., 0] = blue
                table[blue] = np.packbits(self.frame(image).reshape(-1) != 0, bitorder="little")
            table.flags.writeable = False
            self._bit_table = table.reshape(-1)
        return self._bit_table


def white_mask(bgr: np.ndarray, ranges: Sequence[HsvRange]) -> np.ndarray:
    """Convenience: the full-frame mask of `bgr` for `ranges`."""
    return WhiteMask(ranges).frame(bgr)

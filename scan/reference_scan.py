"""The executable specification of the paper's Algorithm 1 (HSV mask + radial scan), written for clarity.

This is deliberately the slow, pixel-by-pixel walk of the pseudo-code. The fast scan
(`radial_scan.RadialScanner`) must return exactly what this returns, hit for hit; the tests and
`courtloc bench preprocess` both use this module as the yardstick. Change the rules here first.

Rules fixed here (documented in docs/preprocess.md):
- Rays: ray k has angle a_k = angle_start + k * step degrees (inclusive of angle_stop), origin (cx, cy)
  = (W/2, H-1) unless configured; d = 0, 1, ..., max(H, W) (inclusive).
- Sample: x = cx + d*cos(a), y = cy - d*sin(a) in float64 with math.cos/math.sin of math.radians(a);
  pixel column = to_pixel(x), row = to_pixel(y), where to_pixel truncates toward zero (int(), the
  default, matching the seed images) or rounds half up (floor(v + 0.5)), per `ScanConfig.rounding`.
- Samples outside the image (row or column out of range) are skipped: they are neither hits nor
  "previous" samples. The previous sample of a hit is the last in-image sample before it on the same ray.
- Hit: the previous in-image sample is white and this one is not. The hit is reported at this sample's
  (row, col, ray index k, d). Consecutive samples on a ray that round to the same pixel are kept; they
  cannot make or break a hit because a pixel is never both white and not white.
- Output: int16 (N, 4) rows (row, col, ray, d), ordered by ray, then by d.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from courtloc.scan.config import PreprocessConfig, ScanConfig
from courtloc.scan.hsv_mask import white_mask


def round_half_up(value: float) -> int:
    return math.floor(value + 0.5)


def to_pixel_function(rounding: str) -> Callable[[float], int]:
    """The scan's float -> pixel index rule; `int` truncates toward zero, so -0.7 becomes pixel 0."""
    return {"trunc": int, "half_up": round_half_up}[rounding]


def reference_scan(mask: np.ndarray, scan: ScanConfig) -> np.ndarray:
    """Walk every ray pixel by pixel over a (H, W) mask (non-zero = white)."""
    height, width = mask.shape
    cx, cy = scan.origin_for(height, width)
    max_d = scan.max_d_for(height, width)
    to_pixel = to_pixel_function(scan.rounding)
    hits: list[tuple[int, int, int, int]] = []
    for ray, angle_deg in enumerate(scan.angles_deg()):
        a = math.radians(angle_deg)
        cos_a, sin_a = math.cos(a), math.sin(a)
        previous_white: bool | None = None  # None: no in-image sample yet on this ray
        for d in range(max_d + 1):
            col = to_pixel(cx + d * cos_a)
            row = to_pixel(cy - d * sin_a)
            if not (0 <= row < height and 0 <= col < width):
                continue
            white = bool(mask[row, col] != 0)
            if previous_white is True and not white:
                hits.append((row, col, ray, d))
            previous_white = white
    return np.array(hits, dtype=np.int16).reshape(-1, 4)


def reference_preprocess(bgr: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """BGR frame -> HSV white mask (full frame) -> `reference_scan` hits."""
    return reference_scan(white_mask(bgr, config.hsv_ranges), config.scan)

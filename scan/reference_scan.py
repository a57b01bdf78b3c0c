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
- Edge drop (ours, not the paper's; `ScanConfig.min_edge_drop`, 0 = off): a hit also needs the previous
  sample's brightness (HSV V = max(B, G, R)) to exceed the darkest of the hit's pixel and the next
  `edge_drop_samples` - 1 pixels on the ray (distinct pixels, in image) by at least `min_edge_drop`.
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


def _ray_pixels(ray_angle_deg: float, height: int, width: int, scan: ScanConfig) -> list[tuple[int, int, int]]:
    """(row, col, d) of the in-image samples of one ray, in order of d."""
    cx, cy = scan.origin_for(height, width)
    to_pixel = to_pixel_function(scan.rounding)
    a = math.radians(ray_angle_deg)
    cos_a, sin_a = math.cos(a), math.sin(a)
    samples = []
    for d in range(scan.max_d_for(height, width) + 1):
        col = to_pixel(cx + d * cos_a)
        row = to_pixel(cy - d * sin_a)
        if 0 <= row < height and 0 <= col < width:
            samples.append((row, col, d))
    return samples


def _drop_after(brightness: np.ndarray, samples: list[tuple[int, int, int]], i: int, span: int) -> int:
    """Brightness of the sample before i less the darkest of sample i's pixel and the span - 1 distinct
    pixels after it."""
    pixels: list[tuple[int, int]] = []
    for row, col, _ in samples[i:]:
        if not pixels or pixels[-1] != (row, col):
            pixels.append((row, col))
        if len(pixels) == span:
            break
    before = samples[i - 1]
    return int(brightness[before[0], before[1]]) - min(int(brightness[r, c]) for r, c in pixels)


def reference_scan(mask: np.ndarray, scan: ScanConfig, brightness: np.ndarray | None = None) -> np.ndarray:
    """Walk every ray pixel by pixel over a (H, W) mask (non-zero = white); with `brightness` (H, W) and
    `scan.min_edge_drop` > 0, keep only hits with that edge drop."""
    height, width = mask.shape
    drop = scan.min_edge_drop if brightness is not None else 0
    hits: list[tuple[int, int, int, int]] = []
    for ray, angle_deg in enumerate(scan.angles_deg()):
        samples = _ray_pixels(angle_deg, height, width, scan)
        for i, (row, col, d) in enumerate(samples):
            white = bool(mask[row, col] != 0)
            previous_white = i > 0 and bool(mask[samples[i - 1][0], samples[i - 1][1]] != 0)
            if previous_white and not white and (
                    drop == 0 or _drop_after(brightness, samples, i, scan.edge_drop_samples) >= drop):
                hits.append((row, col, ray, d))
    return np.array(hits, dtype=np.int16).reshape(-1, 4)


def reference_preprocess(bgr: np.ndarray, config: PreprocessConfig) -> np.ndarray:
    """BGR frame -> HSV white mask (full frame) -> `reference_scan` hits (with the edge drop of the
    frame's brightness, V = max(B, G, R))."""
    return reference_scan(white_mask(bgr, config.hsv_ranges), config.scan, bgr.max(axis=2))

"""Converting between hits and the seed dataset's dot images, both ways.

The seed images (the paper authors' recordings) are the scan's output already drawn: black frames with
white filled circles of radius 2 (13 pixels, `cv2.circle` shape) at each hit, saved as JPEG. So models
trained on them can run on live hits (`draw_hits`), and live-hit models can use the seed data
(`dots_to_hits` + `centroids_to_hits`).
"""
from __future__ import annotations

from typing import Optional

import cv2
import numpy as np

from courtloc.common.payloads import HIT_DTYPE
from courtloc.scan.config import ScanConfig
from courtloc.scan.radial_scan import RadialScanner, empty_hits

# JPEG noise in the seed images stays below ~16 and dot pixels above ~240; anything between is safe.
DEFAULT_THRESHOLD = 127


def dot_offsets(radius: int) -> np.ndarray:
    """(K, 2) int (d_row, d_col) of the pixels of a filled `cv2.circle` of `radius` (13 for radius 2)."""
    size = 2 * radius + 1
    canvas = np.zeros((size, size), np.uint8)
    cv2.circle(canvas, (radius, radius), radius, 255, thickness=-1)
    return np.argwhere(canvas > 0) - radius


def stamp_dots(canvas: np.ndarray, rows: np.ndarray, cols: np.ndarray, radius: int, value: float | int,
               row_offset: int = 0) -> np.ndarray:
    """Set the dot of radius `radius` around each (row - row_offset, col) of `canvas` to `value`.

    Equal to calling cv2.circle(filled) per dot, clipped at the borders, without a Python loop.
    """
    offsets = dot_offsets(radius)
    r = rows.astype(np.int64)[:, None] + offsets[None, :, 0] - row_offset
    c = cols.astype(np.int64)[:, None] + offsets[None, :, 1]
    inside = (r >= 0) & (r < canvas.shape[0]) & (c >= 0) & (c < canvas.shape[1])
    canvas[r[inside], c[inside]] = value
    return canvas


def draw_hits(hits: np.ndarray, height: int, width: int, radius: int = 2) -> np.ndarray:
    """The paper's dot image of `hits` ((N, >=2) row, col first): uint8 (H, W), 255 dots on 0."""
    canvas = np.zeros((height, width), np.uint8)
    if len(hits):
        stamp_dots(canvas, hits[:, 0], hits[:, 1], radius, 255)
    return canvas


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    raise ValueError(f"expected a grey (H, W) or BGR (H, W, 3) image, got shape {image.shape}")


def dots_to_hits(image: np.ndarray, threshold: int = DEFAULT_THRESHOLD, radius: int = 2,
                 split_touching: bool = True) -> np.ndarray:
    """Dot centres of a seed-style image: float32 (N, 2) (row, col), sorted by row then column.

    Threshold, then connected components. Dots that touch merge into one component, so inside each
    component the centres are found as the pixels where a whole dot of `radius` fits (erosion by the
    dot's own shape); a component in which no whole dot fits (a damaged or differently drawn dot)
    contributes its centroid instead. With `split_touching=False` every component gives its centroid
    only: fewer points, but none guessed, which is what a geometric fit wants (a guessed centre one
    pixel off on a far row moves its floor point by decimetres; docs/localizer.md).
    """
    binary = (_gray(image) > threshold).astype(np.uint8)
    n_labels, labels, _, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n_labels <= 1:
        return np.zeros((0, 2), np.float32)
    if not split_touching:
        points = centroids[1:, ::-1]
        order = np.lexsort((points[:, 1], points[:, 0]))
        return points[order].astype(np.float32)
    kernel = np.zeros((2 * radius + 1, 2 * radius + 1), np.uint8)
    offsets = dot_offsets(radius) + radius
    kernel[offsets[:, 0], offsets[:, 1]] = 1
    # Replicating the border lets a dot cut by the frame edge still fit where its centre is.
    eroded = cv2.erode(binary, kernel, borderType=cv2.BORDER_REPLICATE)
    centre_rows, centre_cols = np.nonzero(eroded)
    has_centre = np.zeros(n_labels, bool)
    has_centre[labels[centre_rows, centre_cols]] = True
    fallback = np.flatnonzero(~has_centre[1:]) + 1
    points = np.concatenate([
        np.stack([centre_rows, centre_cols], axis=1).astype(np.float64),
        centroids[fallback][:, ::-1],  # OpenCV gives (x, y)
    ])
    order = np.lexsort((points[:, 1], points[:, 0]))
    return points[order].astype(np.float32)


def centroids_to_hits(centroids: np.ndarray, height: int, width: int, scan: Optional[ScanConfig] = None,
                      scanner: Optional[RadialScanner] = None) -> np.ndarray:
    """(N, 2) (row, col) points -> int16 (N, 4) hits (row, col, ray, d), ordered by ray then d.

    row and col are the nearest pixel (rounded half up). Of the rays whose angle is within a step of
    the pixel's bearing from the scan origin, the nearest that visits the pixel is taken, and d is the
    first d at which it does (what the scan would report). If none visits it (a dot that is not a scan
    sample), the nearest ray and the rounded distance from the origin are used.
    Points outside the frame are dropped.
    """
    scanner = scanner or RadialScanner(scan or ScanConfig())
    scan = scanner.scan
    if len(centroids) == 0:
        return empty_hits()
    # The nearest pixel to each point (centres of whole dots are integral already).
    rows = np.floor(centroids[:, 0].astype(np.float64) + 0.5).astype(np.int64)
    cols = np.floor(centroids[:, 1].astype(np.float64) + 0.5).astype(np.int64)
    keep = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    rows, cols = rows[keep], cols[keep]
    cx, cy = scan.origin_for(height, width)
    # Where the pixel's samples lie in continuous coordinates: truncation maps [c, c+1) to pixel c.
    centre = 0.5 if scan.rounding == "trunc" else 0.0
    dx, dy = cols + centre - cx, cy - (rows + centre)
    position = (np.degrees(np.arctan2(dy, dx)) - scan.angle_start_deg) / scan.angle_step_deg
    nearest = np.clip(np.rint(position), 0, scan.n_rays - 1).astype(np.int64)
    ray = nearest.copy()
    d = np.rint(np.hypot(dx, dy)).astype(np.int64)
    table = scanner.table(height, width)
    flat = rows * width + cols
    for i in range(len(rows)):
        # Near the origin a pixel is visited by several rays: take the angularly nearest that visits it.
        for k in sorted({nearest[i] - 1, nearest[i], nearest[i] + 1}, key=lambda k: abs(k - position[i])):
            if not 0 <= k < scan.n_rays:
                continue
            start, stop = table.ray_start[k], table.ray_start[k + 1]
            found = np.flatnonzero(table.sample_flat[start:stop] == flat[i])
            if len(found):
                ray[i], d[i] = k, table.sample_hit[start + found[0], 3]
                break
    hits = np.stack([rows, cols, ray, d], axis=1)
    order = np.lexsort((hits[:, 3], hits[:, 2]))
    return hits[order].astype(HIT_DTYPE)


def image_to_hits(image: np.ndarray, scan: Optional[ScanConfig] = None, threshold: int = DEFAULT_THRESHOLD,
                  radius: int = 2, split_touching: bool = True) -> np.ndarray:
    """A seed dot image straight to int16 (N, 4) hits."""
    centres = dots_to_hits(image, threshold, radius, split_touching)
    return centroids_to_hits(centres, image.shape[0], image.shape[1], scan)


__all__ = ["DEFAULT_THRESHOLD", "centroids_to_hits", "dot_offsets", "dots_to_hits", "draw_hits",
           "image_to_hits", "stamp_dots"]

"""Top-down signed distance field of a court's white paint, built at load time from the court geometry.

Value at a floor point: metres to the nearest boundary of the white area, positive outside white,
negative inside. A scan hit lies just beyond the far edge of a white band, so a correct pose puts every
hit on the zero level with the field's gradient (pointing from white to not-white) along the scan ray.

The field is exact for rectangles and straight painted lines and first-order exact for elliptical arcs
(distance = F / |grad F|, which is what matters within a few centimetres of the paint). Painted elements
are combined in the court's painting order: white paint is a union (min), any later non-white paint
cuts it away (max with the negated element). Shapes without an analytic form fall back to a distance
transform of the court's own raster.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

log = logging.getLogger(__name__)


def _box_sdf(x: np.ndarray, y: np.ndarray, cx: float, cy: float, hx: float, hy: float) -> np.ndarray:
    qx = np.abs(x - cx) - hx
    qy = np.abs(y - cy) - hy
    outside = np.hypot(np.maximum(qx, 0.0), np.maximum(qy, 0.0))
    return outside + np.minimum(np.maximum(qx, qy), 0.0)


def _oriented_box_sdf(x: np.ndarray, y: np.ndarray, a: np.ndarray, b: np.ndarray, half_width: float,
                      extend: float) -> np.ndarray:
    d = b - a
    length = float(np.hypot(*d))
    u = d / length
    mid = (a + b) / 2
    # Coordinates along and across the segment, then an axis-aligned box in that frame.
    s = (x - mid[0]) * u[0] + (y - mid[1]) * u[1]
    t = -(x - mid[0]) * u[1] + (y - mid[1]) * u[0]
    return _box_sdf(s, t, 0.0, 0.0, length / 2 + extend, half_width)


def _ellipse_sdf(x: np.ndarray, y: np.ndarray, cx: float, cy: float, a: float, b: float) -> np.ndarray:
    """First-order signed distance to an ellipse: F / |grad F| with F = (dx/a)^2 + (dy/b)^2 - 1."""
    dx, dy = x - cx, y - cy
    f = (dx / a) ** 2 + (dy / b) ** 2 - 1.0
    g = 2.0 * np.hypot(dx / a**2, dy / b**2)
    return f / np.maximum(g, 1e-9)


def _sector_clip(x: np.ndarray, y: np.ndarray, cx: float, cy: float, semi: tuple[float, float],
                 start_deg: float, end_deg: float) -> np.ndarray | None:
    """Signed distance-like value of the angular sector [start, end] of an ellipse (None: full turn)."""
    sweep = end_deg - start_deg
    if abs(sweep) >= 360.0:
        return None
    a, b = semi
    ts, te = math.radians(start_deg), math.radians(end_deg)
    ds = np.array([a * math.cos(ts), b * math.sin(ts)])
    de = np.array([a * math.cos(te), b * math.sin(te)])
    ds /= np.linalg.norm(ds)
    de /= np.linalg.norm(de)
    dx, dy = x - cx, y - cy
    # Inside the sector: left of the start ray and right of the end ray (counter-clockwise sweep).
    left_of_start = -(ds[0] * dy - ds[1] * dx)
    right_of_end = -(dx * de[1] - dy * de[0])
    if sweep <= 180.0:
        return np.maximum(left_of_start, right_of_end)
    return np.minimum(left_of_start, right_of_end)


def _arc_sdf(x: np.ndarray, y: np.ndarray, line) -> np.ndarray:  # line: courtloc.world.court.ArcLine
    cx, cy = line.centre
    a, b = line.semi_axes
    hx, hy = line.width_x / 2, line.width_y / 2
    band = np.maximum(_ellipse_sdf(x, y, cx, cy, a + hx, b + hy), -_ellipse_sdf(x, y, cx, cy, a - hx, b - hy))
    clip = _sector_clip(x, y, cx, cy, (a, b), line.start_deg, line.end_deg)
    return band if clip is None else np.maximum(band, clip)


def _shape_sdf(x: np.ndarray, y: np.ndarray, shape) -> np.ndarray | None:
    if shape.kind == "rect":
        x0, x1 = sorted((shape.x0, shape.x1))
        y0, y1 = sorted((shape.y0, shape.y1))
        return _box_sdf(x, y, (x0 + x1) / 2, (y0 + y1) / 2, (x1 - x0) / 2, (y1 - y0) / 2)
    return None  # polygons and ellipse sectors: no analytic form here


def _mirror(fn):
    return lambda x, y: fn(-x, -y)


def _bbox(polys: list[np.ndarray]) -> tuple[float, float, float, float]:
    pts = np.vstack(polys)
    return float(pts[:, 0].min()), float(pts[:, 0].max()), float(pts[:, 1].min()), float(pts[:, 1].max())


def _mirror_bbox(b: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    return -b[1], -b[0], -b[3], -b[2]


Element = tuple[bool, object, tuple[float, float, float, float]]


def _element_sdfs(court) -> list[Element] | None:
    """(is_white, sdf(x, y), bbox) per painted element in painting order; None if one has no analytic form."""
    out: list[Element] = []
    for region in court.regions:
        white = region.colour in court.white_colours
        if not white and not any(w for w, _, _ in out):
            # Nothing white painted yet: it cuts nothing away. (robocon2025's shaded three-point areas,
            # ellipse sectors with no analytic form here, sent its whole field to the raster fallback,
            # whose staircase gradients pinned a view of one arc to a cm in any rotation about its centre.)
            continue
        if any(_shape_sdf(np.zeros(1), np.zeros(1), s) is None for s in region.shapes + region.holes):
            return None

        def region_sdf(x, y, region=region):
            d = np.min([_shape_sdf(x, y, s) for s in region.shapes], axis=0)
            for hole in region.holes:
                d = np.maximum(d, -_shape_sdf(x, y, hole))
            return d

        box = _bbox([s.polygon() for s in region.shapes])
        out.append((white, region_sdf, box))
        if region.mirror:
            out.append((white, _mirror(region_sdf), _mirror_bbox(box)))
    for line in court.lines:
        white = line.colour in court.white_colours
        if line.kind == "segment":
            def line_sdf(x, y, line=line):
                return _oriented_box_sdf(x, y, np.asarray(line.a, float), np.asarray(line.b, float),
                                         line.width / 2, line.extend)
        else:
            def line_sdf(x, y, line=line):
                return _arc_sdf(x, y, line)
        box = _bbox([line.polygon()])
        out.append((white, line_sdf, box))
        if line.mirror:
            out.append((white, _mirror(line_sdf), _mirror_bbox(box)))
    return out


@dataclass(frozen=True)
class GridCell:
    """Where bilinear lookups fell: flat index of the lower-left sample and the fractions within the cell."""

    index: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    nx: int

    def nearest(self, values: np.ndarray) -> np.ndarray:
        """Nearest-sample value of a grid-shaped array (same shape as the field) at these points."""
        return values.ravel()[self.index + (self.tx >= 0.5) + (self.ty >= 0.5) * self.nx]


# Bands narrower than twice this are "thin" for the band bias (band_bias.py): at most ~2 scan steps wide
# within the scan's range on a court whose lines are 5-10 cm wide; wide paint (floors) never counts.
THIN_BAND_HALF_WIDTH_M = 0.1


def is_thin_band(half_width: np.ndarray) -> np.ndarray:
    """Where a `band_half_width` value names a thin band (not wide paint, not 'no band')."""
    return (half_width > 0) & (half_width < THIN_BAND_HALF_WIDTH_M)


@dataclass(frozen=True)
class CourtField:
    """Signed distance samples on a regular grid: value[i, j] at (x0 + j * res, y0 + i * res)."""

    values: np.ndarray  # (ny, nx) float32
    x0: float
    y0: float
    resolution: float
    half_width: np.ndarray | None = None  # (ny, nx) see band_half_width(); None on coarse copies

    @classmethod
    def from_court(cls, court, resolution: float = 0.01, margin: float = 1.0, reach: float = 1.0) -> "CourtField":
        """Sample the court's white-paint distance over its floor plus `margin` metres, clipped at +-`reach`."""
        hx, hy = court.floor_half_extent_m
        hx, hy = hx + margin, hy + margin
        nx = int(math.ceil(2 * hx / resolution)) + 1
        ny = int(math.ceil(2 * hy / resolution)) + 1
        xs = (-hx + resolution * np.arange(nx)).astype(np.float32)
        ys = (-hy + resolution * np.arange(ny)).astype(np.float32)
        elements = _element_sdfs(court)
        if elements is None:
            values = _raster_sdf(court, xs, ys)
        else:
            # Each element is evaluated only near its own bounding box; farther away the field is
            # clipped at `reach` anyway (nothing downstream looks at distances beyond it).
            values = np.full((ny, nx), reach, np.float32)
            for white, fn, (bx0, bx1, by0, by1) in elements:
                j0 = max(0, int(np.floor((bx0 - reach - xs[0]) / resolution)))
                j1 = min(nx, int(np.ceil((bx1 + reach - xs[0]) / resolution)) + 1)
                i0 = max(0, int(np.floor((by0 - reach - ys[0]) / resolution)))
                i1 = min(ny, int(np.ceil((by1 + reach - ys[0]) / resolution)) + 1)
                if j0 >= j1 or i0 >= i1:
                    continue
                gx, gy = np.meshgrid(xs[j0:j1], ys[i0:i1])
                e = np.clip(fn(gx, gy), -reach, reach).astype(np.float32)
                block = values[i0:i1, j0:j1]
                values[i0:i1, j0:j1] = np.minimum(block, e) if white else np.maximum(block, -e)
        log.debug("court field %dx%d at %.3f m", nx, ny, resolution)
        field = cls(values=np.ascontiguousarray(values, np.float32), x0=float(xs[0]), y0=float(ys[0]),
                    resolution=float(resolution))
        return cls(values=field.values, x0=field.x0, y0=field.y0, resolution=field.resolution,
                   half_width=field.band_half_width())

    def band_half_width(self, reach_m: float = 0.15, near_m: float = 1.0) -> np.ndarray:
        """Per cell inside paint: the depth of the band's middle nearby (= half its width, at most ~reach_m),
        for far-edge residuals; outside paint: the half-width of the nearest paint if that is a thin band
        (< THIN_BAND_HALF_WIDTH_M) within near_m, else 0.

        A hit quantised into a thin line's inside, nearer its near edge, belongs to the far edge,
        which lies (2 * half-width - depth) ahead. A hit just past a thin band's far edge is further out
        than one past a wide band's (band_bias.py): the fit looks up the band it belongs to here.
        """

        depth = np.maximum(-self.values, 0.0).astype(np.float32)
        k = 2 * int(round(reach_m / self.resolution)) + 1
        inside = np.where(depth > 0, cv2.dilate(depth, np.ones((k, k), np.uint8)), 0.0).astype(np.float32)
        paint = depth > 0
        if not paint.any():
            return inside
        # DIST_LABEL_PIXEL numbers the zero (paint) pixels from 1 in raster order, the order of flatnonzero.
        dist, labels = cv2.distanceTransformWithLabels((~paint).astype(np.uint8), cv2.DIST_L2, 5,
                                                       labelType=cv2.DIST_LABEL_PIXEL)
        nearest = inside.ravel()[np.flatnonzero(paint)[labels.ravel() - 1]].reshape(inside.shape)
        thin = (nearest < THIN_BAND_HALF_WIDTH_M) & (dist * self.resolution <= near_m)
        return np.where(paint, inside, np.where(thin, nearest, 0.0)).astype(np.float32)

    def point_symmetric(self, tolerance_m: float | None = None) -> bool:
        """Whether the paint is the same rotated half a turn about the centre (then every pose and its mirror
        (-x, -y, yaw + pi) see the same lines). Tolerance: two grid cells by default (arcs are sampled)."""
        v = self.values
        ny, nx = v.shape
        centred = (abs(self.x0 + (nx - 1) * self.resolution + self.x0) < 1e-9
                   and abs(self.y0 + (ny - 1) * self.resolution + self.y0) < 1e-9)
        tol = 2 * self.resolution if tolerance_m is None else tolerance_m
        return bool(centred and np.abs(v - v[::-1, ::-1]).max() <= tol)

    def coarse(self, factor: int, clip: float) -> "CourtField":
        """A subsampled copy with |value| clipped, for the global search (blur-free: min over blocks)."""
        ny, nx = self.values.shape
        ny2, nx2 = ny // factor, nx // factor
        blocks = np.abs(self.values[: ny2 * factor, : nx2 * factor]).reshape(ny2, factor, nx2, factor)
        # Min of |d| over the block: a hit anywhere within the block counts as on the paint edge.
        v = np.minimum(blocks.min(axis=(1, 3)), clip).astype(np.float32)
        r = self.resolution * factor
        return CourtField(values=v, x0=self.x0 + (factor - 1) * self.resolution / 2,
                          y0=self.y0 + (factor - 1) * self.resolution / 2, resolution=r)

    def lookup(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bilinear value and its exact gradient (d/dx, d/dy) at floor points (any shape); clamped at the border."""
        inv = 1.0 / self.resolution
        value, gx, gy, _ = self.lookup_grid((x - self.x0) * inv, (y - self.y0) * inv)
        return value, gx * inv, gy * inv

    def lookup_grid(self, fx: np.ndarray, fy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, "GridCell"]:
        """`lookup` at fractional grid coordinates (column, row); the gradient is per grid cell, not per metre.
        Also returns the cell, so that a second grid can be read at the same points without recomputing it.

        The pose fit works in grid units so that no call is spent converting back and forth.
        """
        ny, nx = self.values.shape
        fx = np.minimum(np.maximum(fx, 0.0), nx - 1.001)
        fy = np.minimum(np.maximum(fy, 0.0), ny - 1.001)
        ix = fx.astype(np.intp)
        iy = fy.astype(np.intp)
        tx = fx - ix
        ty = fy - iy
        cell = iy * nx + ix
        # One gather for the four corners (per-call overhead, not arithmetic, sets the speed at ~100 hits),
        # corner on the first axis so that each corner's array is contiguous for the arithmetic below.
        v00, v01, v10, v11 = self._flat[cell + self._corner_offsets.reshape((4,) + (1,) * cell.ndim)]
        dx_top = v01 - v00
        dx_bot = v11 - v10
        upper = v00 + dx_top * tx
        lower = v10 + dx_bot * tx
        gy = lower - upper
        value = upper + gy * ty
        gx = dx_top + (dx_bot - dx_top) * ty
        return value, gx, gy, GridCell(index=cell, tx=tx, ty=ty, nx=nx)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_flat", self.values.ravel())
        nx = self.values.shape[1]
        object.__setattr__(self, "_corner_offsets", np.array([0, 1, nx, nx + 1], np.intp))

    def nearest(self, x: np.ndarray, y: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """Nearest-sample value of this field (or of another array on the same grid)."""
        return self.nearest_grid((x - self.x0) / self.resolution, (y - self.y0) / self.resolution, values)

    def nearest_grid(self, fx: np.ndarray, fy: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """`nearest` at fractional grid coordinates (column, row)."""
        ny, nx = self.values.shape
        # minimum/maximum rather than np.clip: the same result without its per-call overhead.
        ix = np.minimum(np.maximum(np.rint(fx).astype(np.intp), 0), nx - 1)
        iy = np.minimum(np.maximum(np.rint(fy).astype(np.intp), 0), ny - 1)
        return (self.values if values is None else values).ravel()[iy * nx + ix]


def _raster_sdf(court, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Fallback: distance transforms of the court's white mask at half the grid spacing."""

    res = float(xs[1] - xs[0]) / 2
    mask, transform = court.white_mask_topdown(res)
    white = (mask > 0).astype(np.uint8)
    d_out = cv2.distanceTransform(1 - white, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
    d_in = cv2.distanceTransform(white, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
    # The boundary lies half a texel from the centres on either side of it.
    sdf = np.where(white > 0, -(d_in - res / 2), d_out - res / 2).astype(np.float32)
    inv = np.linalg.inv(transform)
    gx, gy = np.meshgrid(xs, ys)
    cols = np.clip(np.rint(inv[0, 0] * gx + inv[0, 2]).astype(int), 0, sdf.shape[1] - 1)
    rows = np.clip(np.rint(inv[1, 1] * gy + inv[1, 2]).astype(int), 0, sdf.shape[0] - 1)
    return sdf[rows, cols]

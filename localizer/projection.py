"""Scan hits (image pixels) -> floor points in the robot frame, through the fixed, calibrated camera.

The camera never moves on the robot, so a hit's floor point depends on its pixel only: one table of
H x W floor points, built at load time from the camera (distortion included), answers every hit by a
lookup. The table is what the package's ONNX graph carries (see onnx_graph.py). Robot frame: x forward,
y left, origin at the pose point on the floor.

Each table entry is the floor point of the pixel stepped back `edge_offset_px` towards the scan origin:
the scan reports the first pixel past the paint's far edge, so the edge itself lies slightly before it.

Besides the point, the fit needs per hit
- the unit direction of its scan ray on the floor (image rays from the scan origin are straight, and the
  floor homography keeps them straight, so on the floor they run from the origin's floor point outwards),
- the floor error one pixel causes: range^2 / (f h) along the view, range / f across it,
- the floor length of one scan step (one pixel along the image ray) at the hit's pixel: a line thinner
  than a step is seen only when a sample lands in it, which moves its hits outwards (band_bias.py).

All per-hit arrays are views into one packed (N, 12) array (PACKED_COLUMNS), which the compiled fit
(fit_kernel.c) reads as it is; with the kernel built, hits -> table -> geometry is one C call too.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np

from courtloc.world.camera import CameraModel

try:
    from courtloc.localizer import _fit_kernel
except ImportError:  # built without a C compiler: the numpy path below
    _fit_kernel = None

# Columns of the packed per-hit geometry (fit_kernel.c's H_* constants): point x, y | ray dir x, y |
# sigma along, across | view dir x, y | range | depression | tan(azimuth) | unused.
PACKED_COLUMNS = 12


class ProjectedHits:
    """Floor geometry of a frame's usable hits, robot frame: named views of one packed (N, PACKED_COLUMNS)
    float64 array, made on first use (the compiled fit reads `packed` alone; a plain class, not a
    pydantic model: it is built on every frame from arrays made right here, nothing to validate)."""

    def __init__(self, packed: np.ndarray, camera_xy: complex, camera_height: float) -> None:
        if packed.ndim != 2 or packed.shape[1] != PACKED_COLUMNS:
            raise ValueError(f"packed hits must be (N, {PACKED_COLUMNS}), got {packed.shape}")
        self.packed = packed
        self.camera_xy = camera_xy
        self.camera_height = camera_height

    def __len__(self) -> int:
        return self.packed.shape[0]

    @cached_property
    def points(self) -> np.ndarray:  # (N, 2) metres
        return self.packed[:, 0:2]

    @cached_property
    def ray_dirs(self) -> np.ndarray:  # (N, 2) unit, outward along the scan ray
        return self.packed[:, 2:4]

    @cached_property
    def sigma(self) -> np.ndarray:  # (N, 2) metres of floor error per pixel: (along the view, across it)
        return self.packed[:, 4:6]

    @cached_property
    def view_dirs(self) -> np.ndarray:  # (N, 2) unit, from the camera to the point
        return self.packed[:, 6:8]

    @cached_property
    def range_m(self) -> np.ndarray:  # (N,) metres from the camera
        return self.packed[:, 8]

    @cached_property
    def step_m(self) -> np.ndarray:  # (N,) floor metres per scan step along the ray (0: unknown)
        return self.packed[:, 11]

    # For the per-frame tilt (body pitch/roll) the fit may estimate: each point's angle below the
    # horizon and tan of its azimuth (roll changes that angle in proportion to it).
    @cached_property
    def depression(self) -> np.ndarray:
        return self.packed[:, 9]

    @cached_property
    def tan_azimuth(self) -> np.ndarray:
        return self.packed[:, 10]

    # The same vectors as complex numbers (x + iy), for the numpy fit's arithmetic.
    @cached_property
    def cpoints(self) -> np.ndarray:
        return self.packed[:, 0:2].view(np.complex128)[:, 0]

    @cached_property
    def cray(self) -> np.ndarray:
        return self.packed[:, 2:4].view(np.complex128)[:, 0]

    @cached_property
    def cview(self) -> np.ndarray:
        return self.packed[:, 6:8].view(np.complex128)[:, 0]


def scan_origin_rc(camera: CameraModel) -> tuple[float, float]:
    """The radial scan starts at the bottom-centre pixel (W/2, H) in the paper's pipeline."""
    return float(camera.height), camera.width / 2.0


def build_floor_table(camera: CameraModel, edge_offset_px: float, max_range_m: float) -> np.ndarray:
    """(H * W, 2) float32 floor point of every pixel, NaN where the pixel sees no floor within range."""
    rows, cols = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rows, cols = rows.ravel(), cols.ravel()
    r0, c0 = scan_origin_rc(camera)
    dr, dc = rows - r0, cols - c0
    norm = np.maximum(np.hypot(dr, dc), 1e-9)
    uv = np.stack([cols - edge_offset_px * dc / norm, rows - edge_offset_px * dr / norm], axis=1)
    pts = camera.pixel_to_floor(uv)
    rng = np.hypot(pts[:, 0] - camera.mount.x, pts[:, 1] - camera.mount.y)
    pts[~(rng < max_range_m)] = np.nan
    return pts.astype(np.float32)


def build_step_table(camera: CameraModel) -> np.ndarray:
    """(H * W,) float32 floor length of one scan step at every pixel: the distance between the floor points
    of the pixel and of the point one pixel nearer the scan origin on its ray (NaN: no floor)."""
    rows, cols = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rows, cols = rows.ravel(), cols.ravel()
    r0, c0 = scan_origin_rc(camera)
    dr, dc = rows - r0, cols - c0
    norm = np.maximum(np.hypot(dr, dc), 1e-9)
    here = camera.pixel_to_floor(np.stack([cols, rows], axis=1))
    before = camera.pixel_to_floor(np.stack([cols - dc / norm, rows - dr / norm], axis=1))
    return np.hypot(*(here - before).T).astype(np.float32)


class HitGeometry:
    """Turns a frame's floor points (from the table) into what the pose fit needs."""

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera
        origin = camera.pixel_to_floor(np.array([[scan_origin_rc(camera)[1], scan_origin_rc(camera)[0]]]))[0]
        if not np.all(np.isfinite(origin)):
            raise ValueError("the scan origin pixel sees no floor: check the camera's pitch and height")
        self.origin_floor = origin
        self._cam_xy = np.array([camera.mount.x, camera.mount.y])
        self._camera_xy = complex(*self._cam_xy)
        self._k_along = 1.0 / (camera.fy * camera.mount.height)
        self._k_across = 1.0 / camera.fx
        self.step_table = build_step_table(camera)

    def from_points(self, points: np.ndarray, rows: np.ndarray | None = None,
                    cols: np.ndarray | None = None) -> ProjectedHits:
        """Geometry of the finite rows of `points` (NaN rows: no floor or outside the image); with the hits'
        pixels (`rows`, `cols`, aligned with `points`) also each hit's scan-step length, else 0 (unknown)."""
        pts = np.asarray(points, np.float64)
        finite = np.all(np.isfinite(pts), axis=1)
        pts = pts[finite]
        packed = np.zeros((len(pts), PACKED_COLUMNS))
        if rows is not None and cols is not None:
            steps = lookup_table(self.step_table[:, None], self.camera.width, self.camera.height, rows, cols)
            packed[:, 11] = np.nan_to_num(steps[finite, 0], nan=0.0)
        packed[:, 0:2] = pts
        rel = pts - self._cam_xy
        rng = np.hypot(rel[:, 0], rel[:, 1])
        view = rel / np.maximum(rng, 1e-9)[:, None]
        ray = pts - self.origin_floor
        ray /= np.maximum(np.hypot(ray[:, 0], ray[:, 1]), 1e-9)[:, None]
        packed[:, 2:4] = ray
        packed[:, 4] = rng**2 * self._k_along
        packed[:, 5] = rng * self._k_across
        packed[:, 6:8] = view
        packed[:, 8] = rng
        packed[:, 9] = np.arctan2(self.camera.mount.height, rng)
        packed[:, 10] = np.clip(view[:, 1] / np.maximum(view[:, 0], 1e-3), -3.0, 3.0)
        return ProjectedHits(packed, self._camera_xy, self.camera.mount.height)

    def from_table(self, table: np.ndarray, hits: np.ndarray) -> ProjectedHits:
        """`from_points` of int16 (N, 4) hits (row, col, ...) looked up in a floor table (build_floor_table's
        layout) in one compiled call; the numpy lookup + `from_points` when the kernel is not built."""
        if _fit_kernel is None:
            return self.from_points(lookup_table(table, self.camera.width, self.camera.height, hits[:, 0], hits[:, 1]),
                                    hits[:, 0], hits[:, 1])
        packed = np.empty((len(hits), PACKED_COLUMNS))
        mount = self.camera.mount
        n = _fit_kernel.hit_geometry(table, self.step_table, self.camera.height, self.camera.width, hits, mount.x,
                                     mount.y, mount.height, float(self.origin_floor[0]), float(self.origin_floor[1]),
                                     self._k_along, self._k_across, packed)
        return ProjectedHits(packed[:n], self._camera_xy, mount.height)


def lookup_table(table: np.ndarray, width: int, height: int, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(N, C) entries of a per-pixel (H * W, C) table at integer pixels (floor points: C = 2); NaN for
    pixels outside the image or seeing no floor."""
    r = np.rint(np.asarray(rows)).astype(np.int64)
    c = np.rint(np.asarray(cols)).astype(np.int64)
    inside = (r >= 0) & (r < height) & (c >= 0) & (c < width)
    out = np.full((len(r),) + table.shape[1:], np.nan, np.float32)
    out[inside] = table[r[inside] * width + c[inside]]
    return out


class FloorProjector:
    """Pixel -> floor geometry in numpy (the same table the ONNX graph carries)."""

    def __init__(self, camera: CameraModel, edge_offset_px: float = 0.2, max_range_m: float = 12.0) -> None:
        self.camera = camera
        self.table = build_floor_table(camera, edge_offset_px, max_range_m)
        self.geometry = HitGeometry(camera)

    def lookup(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 2) floor points of integer pixels; NaN for pixels outside the image or seeing no floor."""
        return lookup_table(self.table, self.camera.width, self.camera.height, rows, cols)

    def project(self, rows: np.ndarray, cols: np.ndarray) -> ProjectedHits:
        return self.geometry.from_points(self.lookup(rows, cols), rows, cols)

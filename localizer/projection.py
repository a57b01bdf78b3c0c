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
- the floor error one pixel causes: range^2 / (f h) along the view, range / f across it.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict

from courtloc.sim.camera import CameraModel


class ProjectedHits(BaseModel):
    """Floor geometry of a frame's usable hits, robot frame; arrays of equal length."""

    model_config = ConfigDict(arbitrary_types_allowed=True)
    points: np.ndarray  # (N, 2) float64 metres
    ray_dirs: np.ndarray  # (N, 2) unit, outward along the scan ray
    sigma: np.ndarray  # (N, 2) metres of floor error per pixel: (along the view, across it)
    view_dirs: np.ndarray  # (N, 2) unit, from the camera to the point
    range_m: np.ndarray  # (N,) metres from the camera
    cpoints: np.ndarray  # the same vectors as complex numbers (x + iy), for the fit's arithmetic
    cray: np.ndarray
    cview: np.ndarray
    # For the per-frame tilt (body pitch/roll) the fit may estimate: each point's angle below the
    # horizon and tan of its azimuth (roll changes that angle in proportion to it).
    depression: np.ndarray
    tan_azimuth: np.ndarray
    camera_xy: complex
    camera_height: float


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


class HitGeometry:
    """Turns a frame's floor points (from the table) into what the pose fit needs."""

    def __init__(self, camera: CameraModel) -> None:
        self.camera = camera
        origin = camera.pixel_to_floor(np.array([[scan_origin_rc(camera)[1], scan_origin_rc(camera)[0]]]))[0]
        if not np.all(np.isfinite(origin)):
            raise ValueError("the scan origin pixel sees no floor: check the camera's pitch and height")
        self.origin_floor = origin
        self._cam_xy = np.array([camera.mount.x, camera.mount.y])
        self._k_along = 1.0 / (camera.fy * camera.mount.height)
        self._k_across = 1.0 / camera.fx

    def from_points(self, points: np.ndarray) -> ProjectedHits:
        """Geometry of the finite rows of `points` (NaN rows: no floor or outside the image)."""
        pts = np.asarray(points, np.float64)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        rel = pts - self._cam_xy
        rng = np.hypot(rel[:, 0], rel[:, 1])
        view = rel / np.maximum(rng, 1e-9)[:, None]
        ray = pts - self.origin_floor
        ray /= np.maximum(np.hypot(ray[:, 0], ray[:, 1]), 1e-9)[:, None]
        sigma = np.stack([rng**2 * self._k_along, rng * self._k_across], axis=1)
        h = self.camera.mount.height
        # Built on the per-frame path from arrays made right here: skip pydantic's validation pass.
        return ProjectedHits.model_construct(points=pts, ray_dirs=ray, sigma=sigma, view_dirs=view, range_m=rng,
                             cpoints=pts[:, 0] + 1j * pts[:, 1], cray=ray[:, 0] + 1j * ray[:, 1],
                             cview=view[:, 0] + 1j * view[:, 1],
                             depression=np.arctan2(h, rng),
                             tan_azimuth=np.clip(view[:, 1] / np.maximum(view[:, 0], 1e-3), -3.0, 3.0),
                             camera_xy=complex(*self._cam_xy), camera_height=h)


class FloorProjector:
    """Pixel -> floor geometry in numpy (the same table the ONNX graph carries)."""

    def __init__(self, camera: CameraModel, edge_offset_px: float = 0.2, max_range_m: float = 12.0) -> None:
        self.camera = camera
        self.table = build_floor_table(camera, edge_offset_px, max_range_m)
        self.geometry = HitGeometry(camera)

    def lookup(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 2) floor points of integer pixels; NaN for pixels outside the image or seeing no floor."""
        r = np.rint(np.asarray(rows)).astype(np.int64)
        c = np.rint(np.asarray(cols)).astype(np.int64)
        inside = (r >= 0) & (r < self.camera.height) & (c >= 0) & (c < self.camera.width)
        out = np.full((len(r), 2), np.nan, np.float32)
        out[inside] = self.table[r[inside] * self.camera.width + c[inside]]
        return out

    def project(self, rows: np.ndarray, cols: np.ndarray) -> ProjectedHits:
        return self.geometry.from_points(self.lookup(rows, cols))

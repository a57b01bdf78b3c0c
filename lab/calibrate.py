"""Camera calibration from labelled edge-dot images (the seed format).

Each dot marks where a scan ray from the bottom-centre pixel leaves a white region, so it must lie on a
white edge of the court whose normal faces away from the scan origin. The fit alternates:
1. back-project every dot to the floor with the current camera and match it to the nearest such edge
   point of the court model (analytic edges, `Court.white_edges`);
2. with the matches fixed, solve for the camera by robust least squares on the point-to-edge-line
   distance in pixels (the edge's tangent is projected too, so sliding along an edge costs nothing).
Parameters: focal length (fx = fy), height, pitch, roll, mount x/y offsets, mount yaw; optionally a
court scale. The principal point stays at the image centre. With `keep_intrinsics` the starting
camera's intrinsics (fx, fy, principal point, distortion from a chessboard calibration) are kept and
only the parameters in `free` are fitted (the mount calibration fits the mount alone).
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from courtloc.sim.edges import dot_centres, scan_hits
from courtloc.sim.labels import PoseLabels, lag_corrected, read_pose_csv
from courtloc.sim.render import Renderer
from courtloc.world.camera import CameraModel
from courtloc.world.court import Court

log = logging.getLogger(__name__)

PARAMETERS = ("f", "height", "pitch", "roll", "mount_x", "mount_y", "mount_yaw")
SEED_LAG_S = 0.0147  # the seed recordings' image->label lag (image at t shows the pose at t + lag)


class DotFrames(BaseModel):
    """Dots of many frames, flattened: pixel (u, v) of each dot and the lag-corrected pose of its frame."""

    model_config = ConfigDict(arbitrary_types_allowed=True)
    uv: np.ndarray  # (N, 2) float
    pose: np.ndarray  # (N, 3) x, y, yaw of the dot's frame
    frame: np.ndarray  # (N,) index into `filenames`
    filenames: list[str]
    width: int
    height: int


class CalibrationResult(BaseModel):
    model_config = ConfigDict(arbitrary_types_allowed=True)
    camera: CameraModel
    court_scale: float
    line_width_change_m: float = 0.0
    frames: int
    dots: int
    inlier_fraction: float
    residual_px_median: float
    residual_px_p95: float
    residual_floor_m_median: float
    residual_floor_m_p95: float
    iterations: int
    parameter_sigma: dict[str, float] = Field(default_factory=dict)

    def report(self) -> str:
        c, m = self.camera, self.camera.mount
        return "\n".join([
            f"frames {self.frames}, dots {self.dots}, inliers {100 * self.inlier_fraction:.1f}%",
            f"f {c.fx:.2f} px  height {m.height:.4f} m  pitch_down {m.pitch:.4f} rad  roll {m.roll:.4f} rad",
            f"mount offset ({m.x:.4f}, {m.y:.4f}) m  mount yaw {m.yaw:.4f} rad  court scale {self.court_scale:.4f}  "
            f"line width change {1000 * self.line_width_change_m:+.1f} mm",
            f"residual px: median {self.residual_px_median:.3f}  p95 {self.residual_px_p95:.3f}",
            f"residual floor m: median {self.residual_floor_m_median:.4f}  p95 {self.residual_floor_m_p95:.4f}",
        ])


class CalibrationOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    frames: int = Field(200, ge=5, description="frames used, spread evenly over the CSV")
    min_dots: int = Field(20, ge=1)
    lag_s: float = SEED_LAG_S
    fit_scale: bool = False
    fit_line_width: bool = Field(False, description="fit one offset of every white edge along its normal")
    iterations: int = Field(12, ge=1, le=100)
    edge_spacing_m: float = Field(0.01, gt=0)
    inlier_px: float = Field(3.0, gt=0, description="robust loss scale and inlier threshold, pixels")
    keep_intrinsics: bool = Field(False, description="keep the starting camera's fx, fy, cx, cy and distortion")
    free: tuple[str, ...] = Field(PARAMETERS, description="camera parameters fitted (the others keep their start)")

    def free_mask(self) -> np.ndarray:
        unknown = set(self.free) - set(PARAMETERS)
        if unknown:
            raise ValueError(f"unknown calibration parameters {sorted(unknown)}; known: {PARAMETERS}")
        return np.array([p in self.free and not (p == "f" and self.keep_intrinsics) for p in PARAMETERS])


# ---- data ------------------------------------------------------------------------------------------
def load_dot_frames(data_dir: str | Path, csv_path: str | Path, frames: int, lag_s: float, min_dots: int = 20,
                    labels: Optional[PoseLabels] = None) -> DotFrames:
    """Dots of `frames` images spread evenly over the CSV, with lag-corrected poses."""

    data_dir = Path(data_dir)
    labels = lag_corrected(labels or read_pose_csv(csv_path), lag_s)
    picks = np.unique(np.linspace(0, len(labels) - 1, min(frames, len(labels))).round().astype(int))
    uv, pose, frame, names = [], [], [], []
    size = None
    for i in picks:
        path = data_dir / labels.filenames[i]
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"cannot read image {path} (row {i + 2} of the CSV)")
        size = image.shape[::-1]
        dots = dot_centres(image)
        if len(dots) < min_dots:
            continue
        uv.append(dots)
        pose.append(np.repeat([[labels.x[i], labels.y[i], labels.yaw[i]]], len(dots), axis=0))
        frame.append(np.full(len(dots), len(names)))
        names.append(labels.filenames[i])
    if not uv:
        raise ValueError(f"no image in {data_dir} has >= {min_dots} dots")
    assert size is not None
    return DotFrames(uv=np.vstack(uv), pose=np.vstack(pose), frame=np.concatenate(frame), filenames=names,
                     width=int(size[0]), height=int(size[1]))


# ---- geometry with one pose per point --------------------------------------------------------------
def _court_to_robot(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    d = points - pose[:, :2]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def _robot_to_court(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    return np.column_stack([c * points[:, 0] - s * points[:, 1] + pose[:, 0],
                            s * points[:, 0] + c * points[:, 1] + pose[:, 1]])


def camera_from_vector(theta: Sequence[float], template: CameraModel, keep_focal: bool = False) -> CameraModel:
    f, height, pitch, roll, mx, my, myaw = theta[:7]
    data = template.model_dump()
    if not keep_focal:
        data.update(fx=float(f), fy=float(f))
    data["mount"].update(height=float(height), pitch=float(pitch), roll=float(roll), x=float(mx), y=float(my),
                         yaw=float(myaw))
    return CameraModel.model_validate(data)


def vector_from_camera(cam: CameraModel) -> np.ndarray:
    m = cam.mount
    return np.array([cam.fx, m.height, m.pitch, m.roll, m.x, m.y, m.yaw])


# ---- fit -------------------------------------------------------------------------------------------
def match_edges(cam: CameraModel, dots: DotFrames, edges: np.ndarray, normals: np.ndarray, tree, scale: float,
                k: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """For each dot: index of the nearest court edge point that faces away from the scan origin (-1 if none)."""
    floor = _robot_to_court(cam.pixel_to_floor(dots.uv), dots.pose) / scale
    origin_px = np.array([[dots.width / 2.0, float(dots.height) - 0.5]])
    origin = _robot_to_court(np.repeat(cam.pixel_to_floor(origin_px), len(dots.uv), axis=0), dots.pose) / scale
    ok = np.all(np.isfinite(floor), axis=1)
    match = np.full(len(floor), -1)
    dist = np.full(len(floor), np.inf)
    if not ok.any():
        return match, dist
    d, idx = tree.query(floor[ok], k=k)
    cand_edges = edges[idx]
    facing = np.einsum("nkj,nkj->nk", normals[idx], cand_edges - origin[ok][:, None, :]) > 0
    d = np.where(facing, d, np.inf)
    best = np.argmin(d, axis=1)
    rows = np.arange(len(best))
    found = np.isfinite(d[rows, best])
    sub_match = np.where(found, idx[rows, best], -1)
    match[ok] = sub_match
    dist[ok] = np.where(found, d[rows, best], np.inf) * scale
    return match, dist


def _unpack(theta: np.ndarray, options: CalibrationOptions, base: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Free parameters -> (7 camera parameters, court scale, edge offset along the white->not-white normal);
    the camera parameters not fitted come from `base`."""
    mask = options.free_mask()
    k = int(mask.sum())
    camera = base.astype(float).copy()
    camera[mask] = theta[:k]
    scale = 1.0
    bleed = 0.0
    if options.fit_scale:
        scale = float(theta[k])
        k += 1
    if options.fit_line_width:
        bleed = float(theta[k])
    return camera, scale, bleed


def _line_residuals(theta: np.ndarray, template: CameraModel, dots: DotFrames, points: np.ndarray,
                    normals: np.ndarray, options: CalibrationOptions) -> np.ndarray:
    """Pixel distance of each dot from the projected edge line through its matched point."""
    cam_theta, scale, bleed = _unpack(theta, options, vector_from_camera(template))
    try:
        cam = camera_from_vector(cam_theta, template, options.keep_intrinsics)
    except ValueError:
        return np.full(len(points), 1e3)
    # A bleed moves every white edge outwards (a line gets 2 * bleed wider); scale stretches the court.
    moved = (points + normals * bleed) * scale
    tangents = np.column_stack([-normals[:, 1], normals[:, 0]])
    p = cam.floor_to_pixel(_court_to_robot(moved, dots.pose))
    q = cam.floor_to_pixel(_court_to_robot(moved + tangents * 0.05, dots.pose))
    t = q - p
    t /= np.linalg.norm(t, axis=1, keepdims=True) + 1e-12
    e = dots.uv - p
    r = e[:, 0] * t[:, 1] - e[:, 1] * t[:, 0]
    return np.nan_to_num(r, nan=1e3, posinf=1e3, neginf=-1e3)


def _subset(dots: DotFrames, use: np.ndarray) -> DotFrames:
    return DotFrames(uv=dots.uv[use], pose=dots.pose[use], frame=dots.frame[use], filenames=dots.filenames,
                     width=dots.width, height=dots.height)


def calibrate(court: Court, dots: DotFrames, initial: CameraModel, options: CalibrationOptions) -> CalibrationResult:
    edges, normals = court.white_edges(options.edge_spacing_m)
    tree = cKDTree(edges)
    if options.keep_intrinsics:
        if (initial.width, initial.height) != (dots.width, dots.height):
            raise ValueError(f"the camera is {initial.width}x{initial.height}, the frames {dots.width}x{dots.height}")
        template = initial
    else:
        template = initial.model_copy(update={"cx": (dots.width - 1) / 2.0, "cy": (dots.height - 1) / 2.0})
    base = vector_from_camera(template)
    theta = base[options.free_mask()]
    if options.fit_scale:
        theta = np.append(theta, 1.0)
    if options.fit_line_width:
        theta = np.append(theta, 0.0)
    # Start loose (matches may be wrong while the camera is far off), then tighten to the inlier scale.
    schedule = np.geomspace(4 * options.inlier_px, options.inlier_px, max(options.iterations // 2, 1))
    iterations = 0
    for it in range(options.iterations):
        iterations = it + 1
        f_scale = float(schedule[min(it, len(schedule) - 1)])
        cam_theta, scale, bleed = _unpack(theta, options, base)
        match, _ = match_edges(camera_from_vector(cam_theta, template, options.keep_intrinsics), dots, edges,
                               normals, tree, scale)
        use = match >= 0
        before = theta.copy()
        fit = least_squares(
            _line_residuals, theta, args=(template, _subset(dots, use), edges[match[use]], normals[match[use]], options),
            loss="soft_l1", f_scale=f_scale, x_scale="jac", max_nfev=50,
        )
        theta = fit.x
        step = np.abs(theta - before)
        full = _unpack(theta, options, base)[0]
        log.info("iteration %d: f %.2f h %.4f pitch %.4f, median |r| %.3f px", it + 1, full[0], full[1], full[2],
                 float(np.median(np.abs(fit.fun))))
        if it >= len(schedule) and _converged(step, options):
            break
    result = _summarise(dots, theta, template, edges, normals, tree, options, iterations)
    result.parameter_sigma = _sigmas(fit.jac, fit.fun, options)
    return result


def _sigmas(jac: np.ndarray, residuals: np.ndarray, options: CalibrationOptions) -> dict[str, float]:
    """1-sigma of each fitted camera parameter from the last Gauss-Newton step: sigma^2 (J^T J)^-1, with
    sigma the residuals' robust spread (1.4826 MAD), as if every residual were independent."""
    names = [p for p, free in zip(PARAMETERS, options.free_mask()) if free]
    spread = 1.4826 * float(np.median(np.abs(residuals - np.median(residuals))))
    try:
        cov = np.linalg.inv(jac.T @ jac) * spread ** 2
    except np.linalg.LinAlgError:
        return {name: math.inf for name in names}
    return {name: float(math.sqrt(max(cov[i, i], 0.0))) for i, name in enumerate(names)}


def _converged(step: np.ndarray, options: CalibrationOptions) -> bool:
    """The last step moved f < 0.01 px, height < 10 um and pitch < 1 urad (the others follow them)."""
    limits = np.array([0.01, 1e-5, 1e-6, np.inf, np.inf, np.inf, np.inf])[options.free_mask()]
    return bool(np.all(step[:len(limits)] < limits))


def _summarise(dots, theta, template, edges, normals, tree, options, iterations) -> CalibrationResult:
    cam_theta, scale, bleed = _unpack(theta, options, vector_from_camera(template))
    cam = camera_from_vector(cam_theta, template, options.keep_intrinsics)
    match, _ = match_edges(cam, dots, edges, normals, tree, scale)
    use = match >= 0
    sub = _subset(dots, use)
    r_px = np.abs(_line_residuals(theta, template, sub, edges[match[use]], normals[match[use]], options))
    floor = _robot_to_court(cam.pixel_to_floor(sub.uv), sub.pose) / scale
    r_m = np.abs(np.einsum("ij,ij->i", floor - edges[match[use]], normals[match[use]]) - bleed) * scale
    return CalibrationResult(
        camera=cam, court_scale=scale, line_width_change_m=2 * bleed, frames=len(dots.filenames), dots=len(dots.uv),
        inlier_fraction=float(np.mean(r_px < options.inlier_px)) * float(use.mean()),
        residual_px_median=float(np.median(r_px)), residual_px_p95=float(np.percentile(r_px, 95)),
        residual_floor_m_median=float(np.median(r_m)), residual_floor_m_p95=float(np.percentile(r_m, 95)),
        iterations=iterations,
    )


def nominal_camera(width: int = 640, height: int = 480, hfov_deg: float = 75.0, mount_height: float = 0.5) -> CameraModel:
    """A deliberately rough starting guess: a level camera with a typical field of view."""
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    return CameraModel(name="nominal", fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2, width=width, height=height,
                       mount={"height": mount_height})


def dot_reproduction(court: Court, camera: CameraModel, data_dir: str | Path, labels: PoseLabels,
                     indices: Sequence[int]) -> np.ndarray:
    """Distance in pixels from each seed dot to the nearest hit of the twin's frame at the labelled pose.

    The twin frame goes through the real preprocess stage; `labels` should be lag-corrected.
    """

    renderer = Renderer(court, camera)
    out = []
    for i in indices:
        image = cv2.imread(str(Path(data_dir) / labels.filenames[i]), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise ValueError(f"cannot read image {labels.filenames[i]} in {data_dir}")
        dots = dot_centres(image)
        hits = scan_hits(renderer.render((float(labels.x[i]), float(labels.y[i]), float(labels.yaw[i]))))
        if len(dots) == 0:
            continue
        if len(hits) == 0:
            out.append(np.full(len(dots), np.inf))
            continue
        out.append(cKDTree(hits[:, [1, 0]].astype(float)).query(dots)[0])
    return np.concatenate(out) if out else np.zeros(0)

"""Camera mount from frames taken at known poses on the court (no other labels).

The robot stands at a pose measured with a tape (x, y, yaw on the court); a few frames are taken there
(more poses make the fit firmer). Each frame goes through the robot's own preprocess (radial-scan
edge hits), and `sim.calibrate`'s edge fit places the camera so the hits fall on the court's line
edges, with the intrinsics from `calibrate intrinsics` kept fixed. Fitted: height, pitch, roll and the
camera's offset on the robot (forward, left, yaw).

Uncertainty: the fit's 1-sigma (Jacobian and the residuals' robust spread), with the frames of one pose
counted as ONE view (they repeat the same picture, so their noise is not independent); a single pose
cannot show a tape-measure error in the pose itself, which moves the offsets by the same amount.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from courtloc.lab.calibrate import (
    CalibrationOptions,
    DotFrames,
    _line_residuals,
    _robot_to_court,
    _subset,
    calibrate,
    match_edges,
)
from courtloc.sim.edges import scan_hits
from courtloc.world.camera import CameraModel
from courtloc.world.court import Court

MOUNT_PARAMETERS = ("height", "pitch", "roll", "mount_x", "mount_y", "mount_yaw")
UNITS = {"height": ("m", 1.0), "pitch": ("deg", 180 / math.pi), "roll": ("deg", 180 / math.pi),
         "mount_x": ("m", 1.0), "mount_y": ("m", 1.0), "mount_yaw": ("deg", 180 / math.pi)}
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


class MountError(ValueError):
    pass


class PoseFrames(BaseModel):
    """Frames taken with the robot standing at one measured pose."""

    model_config = ConfigDict(extra="forbid")
    pose: tuple[float, float, float]
    frames: Path

    @staticmethod
    def parse_pose(text: str) -> tuple[float, float, float]:
        try:
            x, y, yaw = (float(v) for v in text.split(","))
        except ValueError:
            raise MountError(f"--pose {text!r}: expected X,Y,YAW (metres, metres, radians)") from None
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            raise MountError(f"--pose {text!r}: not finite")
        return x, y, yaw


class LineResidual(BaseModel):
    line: str
    hits: int
    median_px: float
    p95_px: float


class MountResult(BaseModel):
    camera: CameraModel
    sigma: dict[str, float]
    frames: int
    poses: int
    hits: int
    inlier_fraction: float
    residual_px_median: float
    residual_px_p95: float
    lines: list[LineResidual] = Field(default_factory=list)

    def report(self) -> str:
        m = self.camera.mount
        values = {"height": m.height, "pitch": m.pitch, "roll": m.roll, "mount_x": m.x, "mount_y": m.y,
                  "mount_yaw": m.yaw}
        out = [f"{self.frames} frames at {self.poses} pose(s), {self.hits} edge hits, "
               f"inliers {100 * self.inlier_fraction:.1f}%"]
        for name in MOUNT_PARAMETERS:
            unit, k = UNITS[name]
            digits = 4 if unit == "m" else 3
            sigma = self.sigma.get(name, math.nan) * k
            out.append(f"{name:<10} {values[name] * k:+.{digits}f} +- {sigma:.{digits}f} {unit}")
        out.append(f"residual px: median {self.residual_px_median:.3f}  p95 {self.residual_px_p95:.3f}")
        return "\n".join(out)

    def check_report(self) -> str:
        out = ["line                                 hits  median_px  p95_px"]
        out += [f"{line.line:<36} {line.hits:>5}  {line.median_px:>9.2f}  {line.p95_px:>6.2f}" for line in self.lines]
        return "\n".join(out)


def frame_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise MountError(f"--frames {folder}: not a directory")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise MountError(f"--frames {folder}: no image files")
    return files


def hits_of_frames(sets: Sequence[PoseFrames], min_hits: int = 20, hits_of=None) -> DotFrames:
    """The preprocess hits of every frame, as `sim.calibrate` dots with the pose of their set."""

    hits_of = hits_of or scan_hits
    uv, pose, frame, names = [], [], [], []
    size: Optional[tuple[int, int]] = None
    for pose_frames in sets:
        for path in frame_files(pose_frames.frames):
            image = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if image is None:
                raise MountError(f"{path}: cannot be read as an image")
            if size is not None and size != (image.shape[1], image.shape[0]):
                raise MountError(f"{path}: {image.shape[1]}x{image.shape[0]}, the others are {size[0]}x{size[1]}")
            size = (image.shape[1], image.shape[0])
            hits = hits_of(image)
            if len(hits) < min_hits:
                continue
            uv.append(hits[:, [1, 0]].astype(float))
            pose.append(np.repeat([pose_frames.pose], len(hits), axis=0))
            frame.append(np.full(len(hits), len(names)))
            names.append(str(path))
    if not uv or size is None:
        raise MountError(f"no frame has >= {min_hits} edge hits: is the court in view and lit?")
    return DotFrames(uv=np.vstack(uv), pose=np.vstack(pose), frame=np.concatenate(frame), filenames=names,
                     width=size[0], height=size[1])


def fit_mount(court: Court, dots: DotFrames, camera: CameraModel, poses: int,
              initial_height: Optional[float] = None, initial_pitch: Optional[float] = None,
              iterations: int = 16) -> MountResult:
    """The camera's mount with `camera`'s intrinsics kept; MountError when the view cannot fix it."""
    mount = camera.mount.model_copy(update={k: v for k, v in (("height", initial_height), ("pitch", initial_pitch))
                                            if v is not None})
    start = camera.model_copy(update={"mount": mount})
    if initial_height is None or initial_pitch is None:
        start = coarse_start(court, dots, start)
    options = CalibrationOptions(keep_intrinsics=True, free=MOUNT_PARAMETERS, iterations=iterations)
    try:
        result = calibrate(court, dots, start, options)
    except ValueError as exc:
        raise MountError(str(exc)) from None
    frames = len(dots.filenames)
    # Frames of one pose repeat one picture: count each pose once (see the module doc).
    inflate = math.sqrt(frames / max(poses, 1))
    sigma = {name: value * inflate for name, value in result.parameter_sigma.items()}
    if not all(math.isfinite(v) for v in sigma.values()):
        raise MountError("the view does not fix the mount (only parallel lines, or too few hits); "
                         "take frames where lines of two directions are in view")
    lines = per_line_residuals(court, dots, result.camera, options)
    return MountResult(camera=result.camera, sigma=sigma, frames=frames, poses=poses, hits=len(dots.uv),
                       inlier_fraction=result.inlier_fraction, residual_px_median=result.residual_px_median,
                       residual_px_p95=result.residual_px_p95, lines=lines)


def coarse_start(court: Court, dots: DotFrames, camera: CameraModel, max_hits: int = 400) -> CameraModel:
    """The (height, pitch) on a grid whose floor projection puts the most hits on a white edge: the edge
    fit only converges from within a few centimetres and degrees, and a new robot's mount is a guess."""

    edges, _ = court.white_edges(0.01)
    tree = cKDTree(edges)
    pick = np.linspace(0, len(dots.uv) - 1, min(max_hits, len(dots.uv))).astype(int)
    uv, pose = dots.uv[pick], dots.pose[pick]
    best, best_score = camera, -1.0
    for height in np.geomspace(0.15, 2.0, 28):
        for pitch in np.linspace(-0.15, 0.8, 58):
            try:
                candidate = CameraModel.model_validate(
                    {**camera.model_dump(), "mount": {**camera.mount.model_dump(), "height": height, "pitch": pitch}})
            except ValueError:  # horizon out of the frame: not a camera that sees the court
                continue
            floor_robot = candidate.pixel_to_floor(uv)
            ok = np.all(np.isfinite(floor_robot), axis=1)
            if ok.sum() < 0.5 * len(uv):
                continue
            floor = _robot_to_court(floor_robot[ok], pose[ok])
            reach = np.linalg.norm(floor_robot[ok], axis=1)
            distance, _ = tree.query(floor, distance_upper_bound=1.0)
            score = float(np.sum(distance < np.maximum(0.03, 0.02 * reach))) / len(uv)
            if score > best_score:
                best, best_score = candidate, score
    return best


def _line_name(normal: np.ndarray, point: np.ndarray) -> str:
    """A straight edge named by the axis it follows and where it lies: 'edge x = +7.45 m (facing +x)'."""
    angle = math.degrees(math.atan2(normal[1], normal[0]))
    for axis, facing, deg in (("x", "+x", 0.0), ("y", "+y", 90.0), ("x", "-x", 180.0), ("x", "-x", -180.0),
                              ("y", "-y", -90.0)):
        if abs(angle - deg) < 3.0:
            value = point[0] if axis == "x" else point[1]
            return f"edge {axis} = {value:+.2f} m (facing {facing})"
    return "curved or oblique edges"


def per_line_residuals(court: Court, dots: DotFrames, camera: CameraModel,
                       options: CalibrationOptions) -> list[LineResidual]:
    """Pixel residual of the hits matched to each straight court edge (curves pooled)."""

    edges, normals = court.white_edges(options.edge_spacing_m)
    match, _ = match_edges(camera, dots, edges, normals, cKDTree(edges), 1.0)
    use = match >= 0
    if not use.any():
        return []
    sub = _subset(dots, use)
    theta = np.array([camera.fx, camera.mount.height, camera.mount.pitch, camera.mount.roll, camera.mount.x,
                      camera.mount.y, camera.mount.yaw])[options.free_mask()]
    r = np.abs(_line_residuals(theta, camera, sub, edges[match[use]], normals[match[use]], options))
    names = np.array([_line_name(normals[i], edges[i]) for i in match[use]])
    out = []
    for name in sorted(set(names)):
        sel = r[names == name]
        out.append(LineResidual(line=str(name), hits=int(len(sel)), median_px=float(np.median(sel)),
                                p95_px=float(np.percentile(sel, 95))))
    return out


def mounted_camera(result: MountResult, name: str) -> CameraModel:
    m = result.camera.mount
    s = result.sigma
    provenance = (f"courtloc calibrate mount: {result.frames} frames at {result.poses} pose(s), residual median "
                  f"{result.residual_px_median:.2f} px; height {m.height:.4f} +- {s.get('height', math.nan):.4f} m, "
                  f"pitch {math.degrees(m.pitch):.3f} +- {math.degrees(s.get('pitch', math.nan)):.3f} deg. "
                  f"Intrinsics: {result.camera.provenance}")
    return result.camera.model_copy(update={"name": name, "provenance": provenance})

"""Camera model: pinhole intrinsics (optional OpenCV-style distortion) and its mount on the robot.

Frames:
- court: metres, origin at the court centre, x along the long side, yaw counter-clockwise from +x.
- robot: origin at the pose point, x forward, y left, z up (floor at z = 0).
- camera (OpenCV): x right, y down, z along the optical axis.

Mount: the camera sits at (x, y, height) in the robot frame; yaw turns it left, pitch tilts it down,
roll turns it about its optical axis (positive lowers the camera's right side).
"""
from __future__ import annotations

import json
import math
from importlib import resources
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

Pose = tuple[float, float, float]

# Robot axes expressed in camera axes for an un-tilted camera looking along robot +x.
_CAM_FROM_ROBOT_BASE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


class CameraMount(BaseModel):
    model_config = ConfigDict(extra="forbid")
    x: float = Field(0.0, description="forward offset of the camera from the pose point, metres")
    y: float = Field(0.0, description="leftward offset, metres")
    height: float = Field(gt=0, description="optical centre above the floor, metres")
    yaw: float = Field(0.0, description="radians, counter-clockwise (left) positive")
    pitch: float = Field(0.0, description="radians, positive tilts the optical axis down")
    roll: float = Field(0.0, description="radians about the optical axis")


class CameraModel(BaseModel):
    """A calibrated camera on the robot. Invalid cameras fail at construction with the reason."""

    model_config = ConfigDict(extra="forbid")
    name: str = "camera"
    fx: float
    fy: float
    cx: float
    cy: float
    width: int = Field(640, gt=0)
    height: int = Field(480, gt=0)
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    mount: CameraMount
    provenance: str = ""

    @model_validator(mode="after")
    def _physically_possible(self) -> "CameraModel":
        for field in ("fx", "fy"):
            if not getattr(self, field) > 0:
                raise ValueError(f"{field} must be a positive focal length in pixels, got {getattr(self, field)}")
        if not (0 <= self.cx <= self.width and 0 <= self.cy <= self.height):
            raise ValueError(f"principal point ({self.cx}, {self.cy}) lies outside the {self.width}x{self.height} image")
        if abs(self.mount.pitch) >= math.pi / 2 or abs(self.mount.roll) >= math.pi / 2:
            raise ValueError("mount pitch and roll must lie within +-90 degrees")
        rows = self.horizon_rows()
        if np.all(rows >= self.height - 1):
            raise ValueError(
                f"horizon below the frame (rows {rows.min():.0f}..{rows.max():.0f}): the camera sees no floor; "
                f"pitch {self.mount.pitch:.3f} rad looks too far up"
            )
        if np.all(rows < 0):
            raise ValueError(
                f"horizon above the frame (rows {rows.min():.0f}..{rows.max():.0f}): pitch {self.mount.pitch:.3f} rad "
                "looks so far down that the camera sees only the floor near the robot, too little court to localise"
            )
        return self

    # ---- rotations ------------------------------------------------------------------------------
    @property
    def has_distortion(self) -> bool:
        return any(getattr(self, k) != 0.0 for k in ("k1", "k2", "p1", "p2", "k3"))

    def robot_from_camera_rotation(self) -> np.ndarray:
        """3x3 mapping camera-frame directions to robot-frame directions."""
        m = self.mount
        cy, sy = math.cos(m.yaw), math.sin(m.yaw)
        cp, sp = math.cos(m.pitch), math.sin(m.pitch)
        cr, sr = math.cos(m.roll), math.sin(m.roll)
        rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
        ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])  # +pitch turns forward (x) towards down (-z)
        rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
        return rz @ ry @ rx @ _CAM_FROM_ROBOT_BASE.T

    def camera_position(self) -> np.ndarray:
        return np.array([self.mount.x, self.mount.y, self.mount.height])

    def intrinsic_matrix(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def distortion_coefficients(self) -> np.ndarray:
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    # ---- projection -----------------------------------------------------------------------------
    def _distort(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = xn * radial + 2 * self.p1 * xn * yn + self.p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + self.p1 * (r2 + 2 * yn * yn) + 2 * self.p2 * xn * yn
        return xd, yd

    def _undistort(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # Fixed-point iteration: converges for the mild lens distortion of robot cameras.
        xn, yn = xd.copy(), yd.copy()
        for _ in range(20):
            r2 = xn * xn + yn * yn
            radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
            dx = 2 * self.p1 * xn * yn + self.p2 * (r2 + 2 * xn * xn)
            dy = self.p1 * (r2 + 2 * yn * yn) + 2 * self.p2 * xn * yn
            xn = (xd - dx) / radial
            yn = (yd - dy) / radial
        return xn, yn

    def robot_to_pixel(self, points_robot: np.ndarray) -> np.ndarray:
        """(N, 3) robot-frame points -> (N, 2) pixels (u, v); NaN for points behind the camera."""
        p = np.atleast_2d(np.asarray(points_robot, float))
        cam = _apply(self.robot_from_camera_rotation().T, p - self.camera_position())
        z = cam[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn, yn = cam[:, 0] / z, cam[:, 1] / z
        if self.has_distortion:
            xn, yn = self._distort(xn, yn)
        uv = np.stack([self.fx * xn + self.cx, self.fy * yn + self.cy], axis=1)
        uv[z <= 1e-9] = np.nan
        return uv

    def floor_to_pixel(self, points_robot_xy: np.ndarray) -> np.ndarray:
        """(N, 2) floor points in the robot frame -> (N, 2) pixels; NaN behind the camera."""
        xy = np.atleast_2d(np.asarray(points_robot_xy, float))
        return self.robot_to_pixel(np.column_stack([xy, np.zeros(len(xy))]))

    def pixel_rays(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 3) ray directions in the robot frame (not normalised)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        xn = (uv[:, 0] - self.cx) / self.fx
        yn = (uv[:, 1] - self.cy) / self.fy
        if self.has_distortion:
            xn, yn = self._undistort(xn, yn)
        rays_cam = np.column_stack([xn, yn, np.ones(len(xn))])
        return _apply(self.robot_from_camera_rotation(), rays_cam)

    def pixel_to_floor(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 2) floor points in the robot frame; NaN at and above the horizon."""
        rays = self.pixel_rays(uv)
        down = rays[:, 2] < -1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(down, -self.mount.height / rays[:, 2], np.nan)
        return self.camera_position()[:2] + rays[:, :2] * s[:, None]

    def horizon_rows(self, columns: np.ndarray | None = None) -> np.ndarray:
        """Image row of the horizon (undistorted) at each column; the floor is below it."""
        cols = np.arange(self.width, dtype=float) if columns is None else np.asarray(columns, float)
        rot = self.robot_from_camera_rotation()
        # A camera-frame ray (xn, yn, 1) is horizontal when its robot-frame z is 0: r20*xn + r21*yn + r22 = 0.
        r = rot[2]
        if abs(r[1]) < 1e-12:
            return np.full(cols.shape, -np.inf if r[2] < 0 else np.inf)
        xn = (cols - self.cx) / self.fx
        yn = -(r[0] * xn + r[2]) / r[1]
        return yn * self.fy + self.cy

    def horizon_row(self) -> float:
        """Lowest image row the horizon reaches: every row below it is floor."""
        return float(np.max(self.horizon_rows(np.array([0.0, self.width - 1.0]))))

    # ---- court <-> robot ------------------------------------------------------------------------
    def court_to_pixel(self, points_court_xy: np.ndarray, pose: Pose) -> np.ndarray:
        return self.floor_to_pixel(court_to_robot(points_court_xy, pose))

    def pixel_to_court(self, uv: np.ndarray, pose: Pose) -> np.ndarray:
        return robot_to_court(self.pixel_to_floor(uv), pose)

    def floor_homography(self, pose: Pose) -> np.ndarray:
        """3x3 mapping court (x, y, 1) on the floor to undistorted pixels (u, v, 1) for a robot pose."""
        x, y, yaw = pose
        c, s = math.cos(yaw), math.sin(yaw)
        robot_from_court = np.array([[c, s, -(c * x + s * y)], [-s, c, s * x - c * y], [0.0, 0.0, 1.0]])
        rot_cam_from_robot = self.robot_from_camera_rotation().T
        t = -rot_cam_from_robot @ self.camera_position()
        # Floor points have z = 0, so the projection keeps the x and y columns plus the translation.
        cam_from_floor = np.column_stack([rot_cam_from_robot[:, 0], rot_cam_from_robot[:, 1], t])
        return self.intrinsic_matrix() @ cam_from_floor @ robot_from_court


def _apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) points -> matrix @ each point, column by column: for 3x3 matrices this avoids BLAS, whose
    threads spin for nothing on a busy robot CPU."""
    return np.stack([points[:, 0] * m[0] + points[:, 1] * m[1] + points[:, 2] * m[2] for m in matrix], axis=1)


def court_to_robot(points_xy: np.ndarray, pose: Pose) -> np.ndarray:
    """(N, 2) court points -> robot frame of a robot at pose (x, y, yaw)."""
    p = np.atleast_2d(np.asarray(points_xy, float)) - np.array(pose[:2])
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]])


def robot_to_court(points_xy: np.ndarray, pose: Pose) -> np.ndarray:
    """(N, 2) robot-frame points -> court frame of a robot at pose (x, y, yaw)."""
    p = np.atleast_2d(np.asarray(points_xy, float))
    c, s = math.cos(pose[2]), math.sin(pose[2])
    return np.column_stack([c * p[:, 0] - s * p[:, 1] + pose[0], s * p[:, 0] + c * p[:, 1] + pose[1]])


def available_cameras() -> list[str]:
    return sorted(p.stem for p in Path(str(resources.files("courtloc.world") / "cameras")).glob("*.json"))


def load_camera(name_or_path: str | Path) -> CameraModel:
    """A camera by packaged name (world/cameras/NAME.json, see available_cameras()) or by JSON path."""

    path = Path(name_or_path)
    if not (path.suffix == ".json" and path.is_file()):
        path = Path(str(resources.files("courtloc.world") / "cameras" / f"{name_or_path}.json"))
        if not path.is_file():
            raise ValueError(f"unknown camera {str(name_or_path)!r}: expected one of {available_cameras()} or a JSON path")
    return CameraModel.model_validate(json.loads(path.read_text()))

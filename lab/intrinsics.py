"""Camera intrinsics: chessboard calibration with OpenCV, and import of a calibration made elsewhere.

The result is a `CameraModel` (pinhole + OpenCV distortion k1, k2, p1, p2, k3). Its mount is a
placeholder until `courtloc calibrate mount` fits it on the court.

Views are refused, each with its reason, before they can spoil the fit: no board found, or a board
whose edges are blurred wider than `max_sharpness_px` (OpenCV's chessboard sharpness: the mean width,
in pixels, of the black-to-white transitions at the corners; a sharp board is 1.5-3 px).
"""
from __future__ import annotations

import logging
import math
import re
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from courtloc.world.camera import CameraModel

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
PLACEHOLDER_MOUNT = {"height": 0.5, "pitch": 0.1}  # replaced by `courtloc calibrate mount`


class IntrinsicsError(ValueError):
    """The calibration cannot be made; the message says why."""


class Board(BaseModel):
    """A chessboard: `cols` x `rows` INNER corners (a board of 10 x 7 squares has 9 x 6), `square_m` apart."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    cols: int = Field(ge=2)
    rows: int = Field(ge=2)
    square_m: float = Field(gt=0)

    @classmethod
    def parse(cls, text: str, square_m: float) -> "Board":
        match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
        if not match:
            raise IntrinsicsError(f"--board {text!r}: expected COLSxROWS inner corners, e.g. 9x6")
        return cls(cols=int(match.group(1)), rows=int(match.group(2)), square_m=square_m)

    @property
    def pattern(self) -> tuple[int, int]:
        return self.cols, self.rows

    def object_points(self) -> np.ndarray:
        """(cols * rows, 3) corner positions on the board plane (z = 0), in OpenCV's corner order."""
        grid = np.mgrid[0:self.cols, 0:self.rows].T.reshape(-1, 2)
        return np.column_stack([grid * self.square_m, np.zeros(len(grid))]).astype(np.float32)


class IntrinsicsOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    min_views: int = Field(8, ge=3, description="usable views needed; fewer is refused")
    max_sharpness_px: float = Field(3.5, gt=0, description="a board blurred wider than this is refused")
    fit_k3: bool = Field(False, description="also fit k3 (needs many views reaching the image corners)")
    name: str = "camera"


class ViewVerdict(BaseModel):
    image: str
    used: bool
    reason: str = ""
    sharpness_px: float = math.nan
    error_px: float = math.nan


class IntrinsicsResult(BaseModel):
    model_config = ConfigDict(arbitrary_types_allowed=True)
    camera: CameraModel
    rms_px: float
    views: list[ViewVerdict]
    fx_sigma: float
    fy_sigma: float

    def report(self) -> str:
        c = self.camera
        used = [v for v in self.views if v.used]
        lines = [f"views used {len(used)} of {len(self.views)}"]
        lines += [f"  refused {v.image}: {v.reason}" for v in self.views if not v.used]
        lines += [f"fx {c.fx:.2f} +- {self.fx_sigma:.2f} px  fy {c.fy:.2f} +- {self.fy_sigma:.2f} px  "
                  f"cx {c.cx:.2f}  cy {c.cy:.2f}  ({c.width}x{c.height})",
                  f"distortion k1 {c.k1:.5f} k2 {c.k2:.5f} p1 {c.p1:.6f} p2 {c.p2:.6f} k3 {c.k3:.5f}",
                  f"reprojection error RMS {self.rms_px:.3f} px (worst view "
                  f"{max((v.error_px for v in used), default=math.nan):.3f} px)"]
        return "\n".join(lines)


def image_files(folder: str | Path) -> list[Path]:
    folder = Path(folder)
    if not folder.is_dir():
        raise IntrinsicsError(f"--images {folder}: not a directory")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise IntrinsicsError(f"--images {folder}: no image files ({', '.join(IMAGE_SUFFIXES)})")
    return files


def find_board(gray: np.ndarray, board: Board, max_sharpness_px: float) -> tuple[Optional[np.ndarray], str, float]:
    """(corners (N, 1, 2) float32 or None, reason when None, sharpness px)."""

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, board.pattern, flags=flags)
    if not found:
        return None, f"no {board.cols}x{board.rows} chessboard found", math.nan
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria)
    sharpness = float(cv2.estimateChessboardSharpness(gray, board.pattern, corners)[0][0])
    if not sharpness <= max_sharpness_px:
        return None, f"blurred: edge width {sharpness:.1f} px > {max_sharpness_px} px", sharpness
    return corners, "", sharpness


def calibrate_intrinsics(images: list[Path], board: Board, options: IntrinsicsOptions) -> IntrinsicsResult:
    """Chessboard calibration of `images`; IntrinsicsError (with every refused view's reason) when it cannot."""

    verdicts: list[ViewVerdict] = []
    corners_per_view: list[np.ndarray] = []
    used_index: list[int] = []
    size: Optional[tuple[int, int]] = None
    for path in images:
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            verdicts.append(ViewVerdict(image=path.name, used=False, reason="cannot be read as an image"))
            continue
        if size is None:
            size = (gray.shape[1], gray.shape[0])
        elif size != (gray.shape[1], gray.shape[0]):
            verdicts.append(ViewVerdict(image=path.name, used=False,
                                        reason=f"{gray.shape[1]}x{gray.shape[0]}, the others are {size[0]}x{size[1]}"))
            continue
        corners, reason, sharpness = find_board(gray, board, options.max_sharpness_px)
        verdicts.append(ViewVerdict(image=path.name, used=corners is not None, reason=reason, sharpness_px=sharpness))
        if corners is not None:
            corners_per_view.append(corners)
            used_index.append(len(verdicts) - 1)
    if len(corners_per_view) < options.min_views or size is None:
        refused = "; ".join(f"{v.image}: {v.reason}" for v in verdicts if not v.used)
        raise IntrinsicsError(f"{len(corners_per_view)} usable views, {options.min_views} needed"
                              + (f" (refused: {refused})" if refused else ""))
    flags = 0 if options.fit_k3 else cv2.CALIB_FIX_K3
    objects = [board.object_points()] * len(corners_per_view)
    rms, matrix, dist, rvecs, tvecs, std_intrinsics, _, per_view = cv2.calibrateCameraExtended(
        objects, corners_per_view, size, None, None, flags=flags)
    for i, err in zip(used_index, np.ravel(per_view)):
        verdicts[i].error_px = float(err)
    dist = np.ravel(dist)
    camera = camera_from_matrix(matrix, dist, size, options.name,
                                f"courtloc calibrate intrinsics: {len(corners_per_view)} views of a "
                                f"{board.cols}x{board.rows} board, {board.square_m} m squares, RMS {rms:.3f} px")
    std = np.ravel(std_intrinsics)
    return IntrinsicsResult(camera=camera, rms_px=float(rms), views=verdicts, fx_sigma=float(std[0]),
                            fy_sigma=float(std[1]))


def camera_from_matrix(matrix: np.ndarray, dist: np.ndarray, size: tuple[int, int], name: str,
                       provenance: str, mount: Optional[dict] = None) -> CameraModel:
    coefficients = [float(v) for v in np.ravel(dist)] + [0.0] * 5
    if any(abs(v) > 0 for v in coefficients[5:]):
        raise IntrinsicsError(f"{len(np.ravel(dist))} distortion coefficients: only k1, k2, p1, p2, k3 "
                              "(OpenCV's 5-parameter / ROS plumb_bob model) are supported")
    k1, k2, p1, p2, k3 = coefficients[:5]
    return CameraModel(name=name, fx=float(matrix[0, 0]), fy=float(matrix[1, 1]), cx=float(matrix[0, 2]),
                       cy=float(matrix[1, 2]), width=int(size[0]), height=int(size[1]), k1=k1, k2=k2, p1=p1, p2=p2,
                       k3=k3, mount=mount or dict(PLACEHOLDER_MOUNT), provenance=provenance)


# ---- import -----------------------------------------------------------------------------------------
def _matrix(node, what: str, path: Path) -> np.ndarray:
    """An OpenCV !!opencv-matrix node, or a ROS {rows, cols, data} map."""
    if node.empty():
        raise IntrinsicsError(f"{path}: no {what}")
    if not node.getNode("dt").empty():  # written by cv::FileStorage (!!opencv-matrix)
        mat = node.mat()
        if mat is None:
            raise IntrinsicsError(f"{path}: {what} is an empty OpenCV matrix")
        return np.asarray(mat, float)
    data = node.getNode("data")
    if data.empty() or not data.isSeq():
        raise IntrinsicsError(f"{path}: {what} has neither an OpenCV matrix nor a 'data' list")
    values = np.array([data.at(i).real() for i in range(data.size())], float)
    rows = int(node.getNode("rows").real()) if not node.getNode("rows").empty() else 1
    return values.reshape(rows, -1)


def import_camera_info(path: str | Path, name: Optional[str] = None) -> CameraModel:
    """A camera from an OpenCV calibration YAML (camera_matrix / distortion_coefficients, as cv::FileStorage
    writes them) or a ROS `camera_info` YAML (camera_matrix.data, distortion_model plumb_bob)."""

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise IntrinsicsError(f"{path}: {exc.strerror or exc}") from None
    if not text.lstrip().startswith("%YAML"):
        text = "%YAML:1.0\n---\n" + text  # ROS writes plain YAML; OpenCV's reader wants the directive
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError) as exc:  # the binding wraps a parse error in SystemError
        cause = exc.__cause__ or exc
        raise IntrinsicsError(f"{path}: not a YAML file OpenCV can read ({' '.join(str(cause).split())})") from None

    def first(*keys: str):
        for key in keys:
            node = storage.getNode(key)
            if not node.empty():
                return node
        return storage.getNode(keys[0])

    model = first("distortion_model")
    if not model.empty() and model.string() not in ("plumb_bob", "rational_polynomial", ""):
        raise IntrinsicsError(f"{path}: distortion_model {model.string()!r} is not supported (plumb_bob only)")
    matrix = _matrix(first("camera_matrix", "K", "cameraMatrix"), "camera_matrix", path)
    if matrix.shape != (3, 3):
        raise IntrinsicsError(f"{path}: camera_matrix is {matrix.shape[0]}x{matrix.shape[1]}, not 3x3")
    dist_node = first("distortion_coefficients", "D", "dist_coeffs", "distCoeffs")
    dist = np.zeros(5) if dist_node.empty() else _matrix(dist_node, "distortion_coefficients", path).ravel()
    width, height = first("image_width", "width"), first("image_height", "height")
    if width.empty() or height.empty():
        raise IntrinsicsError(f"{path}: image_width and image_height are needed")
    camera_name = name or (first("camera_name").string() if not first("camera_name").empty() else path.stem)
    try:
        return camera_from_matrix(matrix, dist, (int(width.real()), int(height.real())), camera_name or path.stem,
                                  f"imported from {path.name}")
    except ValueError as exc:  # CameraModel refuses an impossible camera with the reason
        raise IntrinsicsError(f"{path}: {exc}") from None

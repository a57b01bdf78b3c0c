"""Twin renders of a planar chessboard through a camera model (lens distortion included).

Each output pixel is undistorted to a normalised ray, the ray is intersected with the board plane
(a homography, since the board is flat) and the board texture is sampled there with cv2.remap. The
texture is drawn at `texture_px_per_square` and sampled with area-like smoothing, so a far board is
not aliased into false corners.
"""
from __future__ import annotations

import math
from typing import Sequence

import cv2
import numpy as np

from courtloc.world.camera import CameraModel

Vector = Sequence[float]


def board_texture(cols: int, rows: int, px_per_square: int, margin_squares: int = 1) -> np.ndarray:
    """Grey chessboard of (cols + 1) x (rows + 1) squares with a white margin; uint8."""
    squares_x, squares_y = cols + 1, rows + 1
    h = (squares_y + 2 * margin_squares) * px_per_square
    w = (squares_x + 2 * margin_squares) * px_per_square
    texture = np.full((h, w), 235, np.uint8)
    for j in range(squares_y):
        for i in range(squares_x):
            if (i + j) % 2 == 0:
                y0, x0 = (j + margin_squares) * px_per_square, (i + margin_squares) * px_per_square
                texture[y0:y0 + px_per_square, x0:x0 + px_per_square] = 20
    return texture


def render_board(camera: CameraModel, cols: int, rows: int, square_m: float, rvec: Vector, tvec: Vector,
                 background: int = 120, texture_px_per_square: int = 64) -> np.ndarray:
    """Grey image of the board seen by `camera`; the board's first inner corner is at the board origin.

    `rvec`, `tvec`: the board's pose in the camera frame (OpenCV convention: x_cam = R x_board + t).
    """

    margin = 1
    texture = board_texture(cols, rows, texture_px_per_square, margin)
    # Board metres -> texture pixels: inner corner (0, 0) sits one square plus the margin in.
    scale = texture_px_per_square / square_m
    offset = (margin + 1) * texture_px_per_square - 0.5
    rot, _ = cv2.Rodrigues(np.asarray(rvec, float))
    t = np.asarray(tvec, float).reshape(3)
    # normalised camera point (xn, yn, 1) ~ [r1 r2 t] (X, Y, 1): invert to get board coordinates of a ray.
    board_from_ray = np.linalg.inv(np.column_stack([rot[:, 0], rot[:, 1], t]))
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    xn = (u.ravel() - camera.cx) / camera.fx
    yn = (v.ravel() - camera.cy) / camera.fy
    if camera.has_distortion:
        xn, yn = camera._undistort(xn, yn)
    rays = np.stack([xn, yn, np.ones_like(xn)])
    board = board_from_ray @ rays
    with np.errstate(divide="ignore", invalid="ignore"):
        bx, by = board[0] / board[2], board[1] / board[2]
    front = board[2] > 0  # a ray meeting the plane behind the camera sees background
    map_x = np.where(front, bx * scale + offset, -1e6).reshape(camera.height, camera.width).astype(np.float32)
    map_y = np.where(front, by * scale + offset, -1e6).reshape(camera.height, camera.width).astype(np.float32)
    # Texture pixels per image pixel at the board's distance: smooth by about half of it, so a far
    # board averages its texture instead of aliasing it.
    texture_per_image_px = scale * float(np.linalg.norm(t)) / camera.fx
    sigma = 0.5 * texture_per_image_px
    smooth = cv2.GaussianBlur(texture, (0, 0), sigma) if sigma > 0.3 else texture
    image = cv2.remap(smooth, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    return image


def board_pose_looking_at(distance_m: float, tilt_x_rad: float, tilt_y_rad: float, spin_rad: float,
                          centre_offset: Vector, cols: int, rows: int,
                          square_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(rvec, tvec) of a board whose centre sits `distance_m` in front of the camera (shifted by
    `centre_offset` metres in x, y), tilted about its own x and y axes and spun about its normal."""

    def rot(axis: int, angle: float) -> np.ndarray:
        c, s = math.cos(angle), math.sin(angle)
        m = np.eye(3)
        i, j = [k for k in range(3) if k != axis]
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    r = rot(0, tilt_x_rad) @ rot(1, tilt_y_rad) @ rot(2, spin_rad)
    centre_board = np.array([(cols - 1) * square_m / 2, (rows - 1) * square_m / 2, 0.0])
    centre_cam = np.array([centre_offset[0], centre_offset[1], distance_m])
    t = centre_cam - r @ centre_board
    rvec, _ = cv2.Rodrigues(r)
    return rvec.ravel(), t

"""Camera model: projections both ways, frame transforms, homography, validation of impossible cameras."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from courtloc.world.camera import CameraModel, court_to_robot, load_camera, robot_to_court


def _camera(**mount) -> CameraModel:
    base = dict(x=0.1, y=-0.05, height=0.6, yaw=0.03, pitch=0.12, roll=0.02)
    base.update(mount)
    return CameraModel(fx=400.0, fy=395.0, cx=322.0, cy=241.0, mount=base)


def _floor_pixels(cam: CameraModel, n: int = 500) -> np.ndarray:
    rng = np.random.default_rng(0)
    uv = np.column_stack([rng.uniform(0, cam.width - 1, n), rng.uniform(0, cam.height - 1, n)])
    return uv[uv[:, 1] > cam.horizon_rows(uv[:, 0]) + 5]


@pytest.mark.parametrize("distortion", [{}, {"k1": -0.12, "k2": 0.02, "p1": 0.001, "p2": -0.0015, "k3": -0.002}])
def test_pixel_floor_round_trip(distortion):
    cam = _camera().model_copy(update=distortion)
    uv = _floor_pixels(cam)
    floor = cam.pixel_to_floor(uv)
    assert np.all(np.isfinite(floor))
    np.testing.assert_allclose(cam.floor_to_pixel(floor), uv, atol=1e-6)


def test_floor_point_projects_where_expected():
    cam = CameraModel(fx=400, fy=400, cx=320, cy=240, mount=dict(height=0.5))
    # A level camera: a floor point d metres ahead lands f*h/d pixels below the centre row.
    uv = cam.floor_to_pixel([[2.0, 0.0], [2.0, 0.5]])
    np.testing.assert_allclose(uv[0], [320, 240 + 400 * 0.5 / 2.0])
    assert uv[1, 0] == pytest.approx(320 - 400 * 0.5 / 2.0)  # left of the robot is left in the image
    assert cam.horizon_row() == pytest.approx(240)


def test_above_horizon_is_nan_and_behind_camera_is_nan():
    cam = _camera()
    assert np.all(np.isnan(cam.pixel_to_floor([[320.0, 5.0]])))
    assert np.all(np.isnan(cam.floor_to_pixel([[-3.0, 0.0]])))


def test_court_robot_transforms_invert_each_other():
    pose = (1.5, -2.0, 2.5)
    pts = np.array([[0.0, 0.0], [3.0, 1.0], [-4.0, 2.5]])
    np.testing.assert_allclose(robot_to_court(court_to_robot(pts, pose), pose), pts, atol=1e-12)
    # The robot's forward point lies along its heading.
    np.testing.assert_allclose(robot_to_court([[1.0, 0.0]], pose)[0], [1.5 + math.cos(2.5), -2.0 + math.sin(2.5)])


def test_homography_matches_projection():
    cam = _camera()
    pose = (0.7, 1.2, -0.8)
    court_pts = robot_to_court(cam.pixel_to_floor(_floor_pixels(cam, 50)), pose)
    h = cam.floor_homography(pose)
    proj = np.column_stack([court_pts, np.ones(len(court_pts))]) @ h.T
    np.testing.assert_allclose(proj[:, :2] / proj[:, 2:], cam.court_to_pixel(court_pts, pose), atol=1e-6)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"fx": 0.0}, "fx must be a positive focal length"),
        ({"cx": 900.0}, "principal point"),
        ({"mount": {"height": 0.5, "pitch": -0.9}}, "horizon below the frame"),
        ({"mount": {"height": 0.5, "pitch": 1.2}}, "horizon above the frame"),
        ({"mount": {"height": 0.0}}, "height"),
    ],
)
def test_impossible_cameras_are_refused(change, message):
    data = dict(fx=400.0, fy=400.0, cx=320.0, cy=240.0, mount={"height": 0.5})
    data.update(change)
    with pytest.raises(ValidationError, match=message):
        CameraModel(**data)


def test_packaged_seed_camera_is_the_reference_fit(seed_world):
    import json

    ref = json.loads(seed_world.read_text())["camera"]
    cam = load_camera("seed-gazebo")
    assert cam.fx == pytest.approx(ref["f_px"]) and cam.mount.height == pytest.approx(ref["height_m"])
    assert cam.mount.pitch == pytest.approx(ref["pitch_down_rad"])
    assert (cam.mount.x, cam.mount.y) == pytest.approx(tuple(ref["mount_offset_from_pose_origin_m"]))
    assert cam.mount.yaw == pytest.approx(ref["mount_yaw_offset_rad"])


def test_unknown_camera_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown camera"):
        load_camera("nope")

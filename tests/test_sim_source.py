"""Trajectories and the simulated camera source: motion limits, determinism, bad input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from courtloc.sim.source import SimSource, SimSourceConfig
from courtloc.sim.trajectory import CsvTrajectory, RandomWalkTrajectory, WaypointTrajectory
from courtloc.world.angles import wrap_angle
from courtloc.world.court import load_court


def _speeds(traj, dt: float, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    poses = np.array([traj.pose_at(k * dt) for k in range(int(seconds / dt))])
    lin = np.hypot(*np.diff(poses[:, :2], axis=0).T) / dt
    ang = np.abs([wrap_angle(b - a) for a, b in zip(poses[:-1, 2], poses[1:, 2])]) / dt
    return poses, lin, ang


def test_waypoint_loop_visits_waypoints_within_limits():
    traj = WaypointTrajectory([[0, 0], [2, 0], [2, 1]], speed=1.0, yaw_rate=2.0)
    assert traj.pose_at(0.0)[:2] == pytest.approx((0.0, 0.0))
    poses, lin, ang = _speeds(traj, 0.01, 12.0)
    assert lin.max() <= 1.0 + 1e-6 and ang.max() <= 2.0 + 1e-6
    for wx, wy in [(2, 0), (2, 1)]:
        assert np.min(np.hypot(poses[:, 0] - wx, poses[:, 1] - wy)) < 0.02
    # Driving a leg, the robot faces along it (no given headings).
    mid = poses[np.argmin(np.hypot(poses[:, 0] - 1.0, poses[:, 1]))]
    assert mid[2] == pytest.approx(0.0, abs=1e-6)
    period = traj._legs.total
    assert traj.pose_at(period + 0.3) == pytest.approx(traj.pose_at(0.3))


def test_random_walk_stays_on_court_and_is_reproducible():
    court = load_court("robocon2025")
    a = RandomWalkTrajectory(court, speed=1.5, yaw_rate=2.0, seed=5, margin=0.5)
    b = RandomWalkTrajectory(court, speed=1.5, yaw_rate=2.0, seed=5, margin=0.5)
    poses, lin, ang = _speeds(a, 0.05, 120.0)
    assert np.all(court.contains(poses[:, 0], poses[:, 1], margin=0.49))
    assert lin.max() <= 1.5 + 1e-6 and ang.max() <= 2.0 + 1e-6
    # It covers the court rather than dithering in one place.
    assert np.ptp(poses[:, 0]) > 8 and np.ptp(poses[:, 1]) > 4
    assert b.pose_at(77.7) == pytest.approx(a.pose_at(77.7))


def test_csv_trajectory_reads_seed_format_and_yaw(tmp_path):
    path = tmp_path / "poses.csv"
    z = math.sin(-2.5 / 2)
    path.write_text(f"image_filename,x,y,orientation_z\na.jpg,1.0,2.0,0.0\nb.jpg,1.5,2.0,{z}\n")
    traj = CsvTrajectory(path, fps=10)
    assert traj.pose_at(0.0) == pytest.approx((1.0, 2.0, 0.0))
    assert traj.pose_at(0.1) == pytest.approx((1.5, 2.0, -2.5))
    path2 = tmp_path / "t.csv"
    path2.write_text("t,x,y,yaw\n0.0,0,0,3.0\n1.0,1,0,-3.0\n")
    x, _, yaw = CsvTrajectory(path2, fps=10).pose_at(0.5)
    assert x == pytest.approx(0.5) and abs(yaw) == pytest.approx(math.pi, abs=1e-6)  # the short way round


@pytest.mark.parametrize(
    "text, message",
    [
        ("x,y\n1,2\n", "needs columns"),
        ("x,y,yaw\n1,2,0\n1,abc,0\n", "line 3"),
        ("x,y,yaw\n1,2,nan\n", "non-finite"),
        ("t,x,y,yaw\n0,1,2,0\n0,1,2,0\n", "does not increase"),
        ("x,y,yaw\n", "no poses"),
    ],
)
def test_malformed_trajectory_csv_is_a_clear_error(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        CsvTrajectory(path, fps=30)


def test_source_returns_frames_with_the_true_pose_and_is_deterministic():
    cfg = SimSourceConfig(court="seed-gazebo", trajectory="random_walk", seed=3, fps=10,
                          render={"noise_sigma": (2.0, 4.0), "exposure_gain": (0.9, 1.1)})
    with SimSource(cfg) as a, SimSource(cfg) as b:
        for k in range(4):
            fa, pa = a.read()
            fb, pb = b.read()
            assert fa.shape == (480, 640, 3) and fa.dtype == np.uint8
            np.testing.assert_array_equal(fa, fb)
            assert pa == pb == pytest.approx(a._trajectory.pose_at(k / 10))
        assert a.frame_index == 4 and a.timestamp == pytest.approx(0.4)


def test_source_rejects_poses_outside_the_court(tmp_path):
    cfg = SimSourceConfig(court="robocon2025", waypoints=[[0, 0], [9.0, 0.0]])
    with pytest.raises(ValueError, match=r"waypoints\[1\].*outside court 'robocon2025'"):
        SimSource(cfg).open()
    path = tmp_path / "out.csv"
    path.write_text("x,y,yaw\n0,0,0\n1,0,0\n1,5,0\n")
    with pytest.raises(ValueError, match="row 3.*outside"):
        SimSource(SimSourceConfig(court="robocon2025", trajectory="csv", csv_path=str(path))).open()
    with pytest.raises(ValueError, match="csv_path is required"):
        SimSource(SimSourceConfig(trajectory="csv")).open()


def test_source_config_rejects_unknown_fields_and_reading_unopened():
    with pytest.raises(ValidationError, match="spped"):
        SimSourceConfig(spped=2.0)
    with pytest.raises(RuntimeError, match="not open"):
        SimSource(SimSourceConfig()).read()


def test_waypoints_with_headings_turn_while_driving():
    traj = WaypointTrajectory([[0, 0, 0.0], [2, 0, 1.5]], speed=1.0, yaw_rate=1.0)
    poses, lin, ang = _speeds(traj, 0.01, 8.0)
    assert lin.max() <= 1.0 + 1e-6 and ang.max() <= 1.0 + 1e-6
    at_second = poses[np.argmin(np.hypot(poses[:, 0] - 2.0, poses[:, 1]))]
    assert at_second[2] == pytest.approx(1.5, abs=0.02)
    assert traj.pose_at(1.0)[2] == pytest.approx(0.75, abs=0.01)  # heading changes along the leg

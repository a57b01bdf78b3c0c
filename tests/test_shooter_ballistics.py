"""Physics prior: the solved launch speed really puts the ball through the ring; the fit recovers a model."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from courtloc.shot.ballistics import G, ShotModel, UnreachableShot, fit, rpm_for_speed, solve, vacuum_speed
from courtloc.shot.rpm import RpmTable

EXAMPLE = Path(__file__).resolve().parents[1] / "deploy" / "shooter" / "example_rpm_table.csv"


def _fly_in_time(speed: float, model: ShotModel, distance: float) -> tuple[float, float]:
    """Independent check: integrate in time with scipy, stop where x reaches the ring; (z, vz) there."""
    angle = math.radians(model.launch_angle_deg)

    def rhs(_t: float, s: np.ndarray) -> list[float]:
        _, _, vx, vz = s
        v = math.hypot(vx, vz)
        return [vx, vz, -model.drag_per_m * v * vx, -G - model.drag_per_m * v * vz]

    def reach(_t: float, s: np.ndarray) -> float:
        return s[0] - distance

    reach.terminal = True  # type: ignore[attr-defined]
    start = [0.0, model.release_height_m, speed * math.cos(angle), speed * math.sin(angle)]
    result = solve_ivp(rhs, (0.0, 10.0), start, events=reach, rtol=1e-10, atol=1e-12)
    assert result.t_events[0].size == 1, "the ball never reached the ring's distance"
    z, vz = result.y_events[0][0][1], result.y_events[0][0][3]
    return float(z), float(vz)


@pytest.mark.parametrize("drag", [0.0, 0.02, 0.05])
@pytest.mark.parametrize("distance", [3.0, 5.5, 8.0])
def test_solved_trajectory_passes_through_the_ring_centre(drag: float, distance: float) -> None:
    model = ShotModel(release_height_m=0.8, launch_angle_deg=58.0, drag_per_m=drag)
    shot = solve(distance, model)
    z, vz = _fly_in_time(shot.speed_mps, model, distance)
    assert z == pytest.approx(model.ring_height_m, abs=1e-4)
    assert vz < 0  # on the way down
    assert shot.entry_angle_deg > 0
    # 5 % faster overshoots the ring: the root is a real crossing, not a flat spot
    assert _fly_in_time(shot.speed_mps * 1.05, model, distance)[0] > model.ring_height_m + 0.05


def test_without_drag_speed_matches_the_closed_form() -> None:
    model = ShotModel(release_height_m=1.0, launch_angle_deg=45.0)
    # v^2 = g d^2 / (2 cos^2 a (h0 + d tan a - z)) with d = 5, a = 45 deg: 9.81 * 25 / (5 - 1.43) ...
    expected = math.sqrt(G * 25.0 / (2 * 0.5 * (1.0 + 5.0 - 2.43)))
    assert solve(5.0, model).speed_mps == pytest.approx(expected, rel=1e-9)
    assert vacuum_speed(5.0, model) == pytest.approx(expected, rel=1e-12)


def test_rpm_from_speed_wheel_and_slip() -> None:
    model = ShotModel(wheel_radius_m=0.05, slip=0.5)
    # 10 m/s at slip 0.5 is a 20 m/s wheel surface: 400 rad/s = 3819.7 rpm
    assert rpm_for_speed(10.0, model) == pytest.approx(400.0 * 60 / (2 * math.pi))


def test_more_distance_and_more_drag_need_more_rpm() -> None:
    model = ShotModel(drag_per_m=0.02)
    rpms = [solve(d, model).rpm for d in np.arange(2.5, 10.01, 0.5)]
    assert np.all(np.diff(rpms) > 0)
    assert solve(6.0, replace(model, drag_per_m=0.04)).rpm > solve(6.0, model).rpm > solve(6.0, replace(model, drag_per_m=0.0)).rpm


def test_too_close_for_the_launch_angle_is_unreachable() -> None:
    model = ShotModel(release_height_m=0.9, launch_angle_deg=60.0)
    with pytest.raises(UnreachableShot):
        solve(1.0, model)  # the line of launch passes under the ring
    with pytest.raises(UnreachableShot):
        solve(1.7, model)  # reachable, but still rising at the ring (needs d > 2 * 1.53 / tan 60 = 1.77)


def test_fit_recovers_slip_and_drag() -> None:
    truth = ShotModel(release_height_m=0.9, launch_angle_deg=60.0, drag_per_m=0.035, slip=0.62)
    distances = [2.5, 3.5, 4.5, 5.5, 6.5, 7.5]
    rpms = [solve(d, truth).rpm for d in distances]
    result = fit(distances, rpms, replace(truth, slip=0.9, drag_per_m=0.0))
    assert result.model.slip == pytest.approx(0.62, rel=1e-3)
    assert result.model.drag_per_m == pytest.approx(0.035, abs=5e-4)
    assert result.rms_rpm < 0.5


def test_fit_on_the_shipped_example_table() -> None:
    table = RpmTable.load(EXAMPLE)
    base = ShotModel(release_height_m=0.9, launch_angle_deg=60.0, wheel_radius_m=0.05, slip=0.5)
    result = fit(table.distances_m, table.rpms, base)
    assert result.rms_rpm < 5.0  # the example is the prior rounded to 10 rpm
    assert result.max_rpm <= 10.0
    assert 0.6 < result.model.slip < 0.8
    slip_only = fit(table.distances_m, table.rpms, base, fit_drag=False)
    assert slip_only.rms_rpm > 5 * result.rms_rpm  # drag is visible in the example's curvature

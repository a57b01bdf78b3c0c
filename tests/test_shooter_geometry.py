"""Shot geometry against numbers worked out by hand."""
from __future__ import annotations

import math

import pytest

from courtloc.shot.geometry import Pose2D, ShooterMount, UnreachableAim, aim, ring_for, shooter_position
from courtloc.world.angles import wrap_angle


def test_centred_shooter_3_4_5_triangle() -> None:
    shot = aim(Pose2D(1.0, -1.0, 0.0), (4.0, 3.0, 2.43), ShooterMount(release_height_m=0.93))
    assert shot.horizontal_m == pytest.approx(5.0)  # (3, 4) -> 5
    assert shot.height_m == pytest.approx(1.5)
    assert shot.distance_3d_m == pytest.approx(math.sqrt(25.0 + 2.25))
    assert shot.bearing_rad == pytest.approx(math.atan2(4.0, 3.0))  # 0.9273 rad to the left


def test_forward_offset_shortens_the_shot() -> None:
    shot = aim(Pose2D(0.0, 0.0, None), (5.0, 0.0, 2.43), ShooterMount(forward_m=1.0))
    assert shot.horizontal_m == pytest.approx(4.0)
    assert shot.bearing_rad is None  # no yaw, no bearing; the distance does not need it


def test_lateral_offset_turns_the_robot_so_the_firing_line_hits_the_ring() -> None:
    # d = 5, left = 3: along the firing line sqrt(25 - 9) = 4; facing heading -asin(3/5)
    mount = ShooterMount(left_m=3.0)
    shot = aim(Pose2D(0.0, 0.0, 0.0), (5.0, 0.0, 2.43), mount)
    assert shot.horizontal_m == pytest.approx(4.0)
    assert shot.bearing_rad == pytest.approx(-math.asin(0.6))
    # After turning by the bearing the shooter sits at (1.8, 2.4) and the ring is 4 m straight ahead.
    turned = Pose2D(0.0, 0.0, shot.bearing_rad)
    sx, sy = shooter_position(turned, mount)
    assert (sx, sy) == (pytest.approx(1.8), pytest.approx(2.4))
    ahead = (5.0 - sx) * math.cos(turned.yaw) + (0.0 - sy) * math.sin(turned.yaw)
    across = -(5.0 - sx) * math.sin(turned.yaw) + (0.0 - sy) * math.cos(turned.yaw)
    assert ahead == pytest.approx(4.0)
    assert across == pytest.approx(0.0, abs=1e-12)


def test_bearing_wraps_across_pi() -> None:
    # Facing 3.0 rad, the ring at direction atan2(-0.1, -1) = -3.0419: turn +0.2413, not -6.04.
    shot = aim(Pose2D(0.0, 0.0, 3.0), (-1.0, -0.1, 2.43))
    assert shot.bearing_rad == pytest.approx(math.pi + math.atan(0.1) - 3.0)  # 0.2413
    assert -math.pi <= shot.bearing_rad <= math.pi
    assert wrap_angle(math.pi + 0.5) == pytest.approx(-math.pi + 0.5)
    assert wrap_angle(-7.0) == pytest.approx(-7.0 + 2 * math.pi)


def test_unreachable_inside_the_offset_circle() -> None:
    with pytest.raises(UnreachableAim):
        aim(Pose2D(0.0, 0.0, 0.0), (2.0, 0.0, 2.43), ShooterMount(left_m=3.0))
    with pytest.raises(UnreachableAim):
        aim(Pose2D(0.0, 0.0, 0.0), (0.5, 0.0, 2.43), ShooterMount(forward_m=1.0))


def test_ring_from_the_court_model() -> None:
    positive = ring_for("robocon2025", "positive_x")
    negative = ring_for("robocon2025", "negative_x")
    assert positive[0] > 0 > negative[0]
    assert positive[2] == pytest.approx(2.43)
    assert ring_for("robocon2025", 0) in (positive, negative)
    with pytest.raises(ValueError):
        ring_for("robocon2025", "left")
    with pytest.raises(ValueError):
        ring_for("robocon2025", 7)

"""Where the ring is from the shooter: shot distance, 3D distance and the bearing to turn.

Court frame: origin at the court centre, x along the long side, y across, z up, yaw counter-clockwise
from +x. The shooter sits at a fixed offset on the robot (`forward_m` along the robot's heading,
`left_m` to its left) and fires along the robot's heading.

A shot happens only once the robot faces the ring, so the distance that decides the RPM is the one
*after* turning to face it. Turning about the robot's origin moves an offset shooter, but the
distance along the firing line is then sqrt(d^2 - left^2) - forward, with d the horizontal distance
from the robot's origin to the ring: it does not depend on the current yaw. That matters because the
localizer may give (x, y) without yaw.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Union

from courtloc.world.angles import wrap_angle
from courtloc.world.court import load_court

Basket = Union[str, int]


@dataclass(frozen=True)
class Pose2D:
    x: float
    y: float
    yaw: Optional[float] = None


@dataclass(frozen=True)
class ShooterMount:
    """The shooter's release point in the robot frame (metres)."""

    forward_m: float = 0.0
    left_m: float = 0.0
    release_height_m: float = 0.9


@dataclass(frozen=True)
class Aim:
    """How the shot looks from a pose. `horizontal_m` is the floor distance from the release point to
    the ring centre once the robot faces the ring; `bearing_rad` is how far to turn (counter-clockwise
    positive) to face it, None when the pose has no yaw."""

    horizontal_m: float
    distance_3d_m: float
    height_m: float
    bearing_rad: Optional[float]


class UnreachableAim(ValueError):
    """The ring is inside the shooter's lateral offset circle: no heading puts it on the firing line."""


def shooter_position(pose: Pose2D, mount: ShooterMount) -> tuple[float, float]:
    """Where the release point is now (needs yaw: without it the offset has no direction)."""
    if pose.yaw is None:
        raise ValueError("shooter_position needs the pose's yaw")
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    return (pose.x + c * mount.forward_m - s * mount.left_m,
            pose.y + s * mount.forward_m + c * mount.left_m)


def aim(pose: Pose2D, ring: Sequence[float], mount: ShooterMount = ShooterMount()) -> Aim:
    """The shot from `pose` to the ring centre `ring` = (x, y, z).

    The facing heading h satisfies d * sin(phi - h) = left (the ring lies on the firing line through
    the offset shooter), so h = phi - asin(left / d), where phi is the direction from the robot's
    origin to the ring. Raises UnreachableAim when d <= |left| or the ring would be behind the
    release point.
    """
    dx, dy = ring[0] - pose.x, ring[1] - pose.y
    d = math.hypot(dx, dy)
    if d <= abs(mount.left_m):
        raise UnreachableAim(f"ring {d:.3f} m away is within the shooter's lateral offset {mount.left_m} m")
    along = math.sqrt(d * d - mount.left_m ** 2) - mount.forward_m
    if along <= 0.0:
        raise UnreachableAim(f"ring is behind the release point ({along:.3f} m along the firing line)")
    height = ring[2] - mount.release_height_m
    bearing = None
    if pose.yaw is not None:
        facing = math.atan2(dy, dx) - math.asin(mount.left_m / d)
        bearing = wrap_angle(facing - pose.yaw)
    return Aim(horizontal_m=along, distance_3d_m=math.hypot(along, height), height_m=height, bearing_rad=bearing)


def ring_for(court_name: str, basket: Basket) -> tuple[float, float, float]:
    """The ring centre (x, y, z) of `basket` on the named court model (world/courts/NAME.json, or a path).

    `basket` is 'positive_x' / 'negative_x' (the ring on that half of the court) or an index into the
    court's ring list.
    """

    rings = [(ring.x, ring.y, ring.z) for ring in load_court(court_name).rings]
    if not rings:
        raise ValueError(f"court {court_name!r} has no rings")
    if isinstance(basket, int):
        if not -len(rings) <= basket < len(rings):
            raise ValueError(f"basket index {basket} out of range: court {court_name!r} has {len(rings)} rings")
        return rings[basket]  # type: ignore[return-value]
    if basket not in ("positive_x", "negative_x"):
        raise ValueError(f"basket must be 'positive_x', 'negative_x' or an index, got {basket!r}")
    pick = max if basket == "positive_x" else min
    return pick(rings, key=lambda ring: ring[0])  # type: ignore[return-value]

"""The court's point symmetry: (x, y, yaw) and (-x, -y, yaw + pi) see the same paint.

Modes (LocalizerConfig.symmetry):
- "half": every answer is put in the configured half (`half` = "+x" or "-x"); for a robot that never
  leaves its half. Within `centre_margin_m` of x = 0 position cannot tell, so the heading decides:
  the pose facing towards the configured half's basket (cos(yaw) > 0 for "+x") is taken.
- "previous": the twin closer to the previous pose (tracking continuity); with no previous pose the
  half rule above starts it. This is the default: a robot may cross the centre line.
- "both": like "previous" for the main answer, and the mirror twin is reported as an alternative.
"""
from __future__ import annotations

import math

import numpy as np

from courtloc.localizer.config import Half
from courtloc.world.angles import wrap_angle


def mirror(pose: np.ndarray) -> np.ndarray:
    x, y, yaw = pose
    return np.array([-x, -y, wrap_angle(yaw + math.pi)])


def in_half(pose: np.ndarray, half: Half, centre_margin_m: float) -> bool:
    sign = 1.0 if half == "+x" else -1.0
    if abs(pose[0]) > centre_margin_m:
        return bool(sign * pose[0] > 0)
    return bool(sign * math.cos(pose[2]) >= 0)


def by_half(pose: np.ndarray, half: Half, centre_margin_m: float) -> np.ndarray:
    return pose if in_half(pose, half, centre_margin_m) else mirror(pose)


def by_previous(pose: np.ndarray, previous: np.ndarray, metres_per_rad: float = 1.0) -> np.ndarray:
    """The twin nearer the previous pose; heading counts too (`metres_per_rad`), since near the centre
    point the two twins are close in position but always half a turn apart in heading."""
    twin = mirror(pose)

    def distance(p: np.ndarray) -> float:
        return (math.hypot(p[0] - previous[0], p[1] - previous[1])
                + metres_per_rad * abs(math.remainder(p[2] - previous[2], 2 * math.pi)))

    return pose if distance(pose) <= distance(twin) else twin

"""Angles on the court: yaw is counter-clockwise from +x, in radians, kept in [-pi, pi)."""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

_FULL_TURN = 2.0 * math.pi
AngleT = TypeVar("AngleT", float, np.ndarray)


def wrap_angle(angle: AngleT) -> AngleT:
    """`angle` (a float or an array of them) wrapped to [-pi, pi)."""
    return (angle + math.pi) % _FULL_TURN - math.pi

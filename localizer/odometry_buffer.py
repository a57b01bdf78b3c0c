"""Recent wheel odometry and gyro of one epoch: the motion between two frame times (see odometry_fusion.py)."""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Optional

import numpy as np

from courtloc.world.angles import wrap_angle


@dataclass(frozen=True)
class OdometrySample:
    t: float
    epoch: int
    pose: tuple[float, float, float]  # dead-reckoned in the epoch's frame
    slip: bool
    source_ns: int
    seq: int
    cut: tuple[float, float] = (0.0, 0.0)  # motion the slip limit has removed in this epoch so far (cumulative)


@dataclass(frozen=True)
class OdometryDelta:
    """Motion between two times in the robot frame at the first: forward, left (m), turn (rad); the slip limit
    removed (cut_dx, cut_dy) of the wheels' motion in between (in the same frame; it may have been real)."""

    dx: float
    dy: float
    dyaw: float
    slip: bool
    cut_dx: float = 0.0
    cut_dy: float = 0.0


class OdometryBuffer:
    """Recent odometry of one epoch at a time; answers the motion between two times."""

    def __init__(self, keep_s: float) -> None:
        self.keep_s = keep_s
        self.samples: deque[OdometrySample] = deque()
        # Nothing is dropped while the newest sample is older than this: a snapshot seeded after a restart
        # (`OdometryFusion.resume`) stays until the pose saved with it can have been carried to the first frames.
        self.hold_until = -math.inf

    def add(self, sample: OdometrySample) -> None:
        if self.samples and sample.epoch != self.samples[-1].epoch:
            self.samples.clear()  # differences across epochs mean nothing
        self.samples.append(sample)
        if sample.t <= self.hold_until:
            return
        while self.samples and self.samples[0].t < sample.t - self.keep_s:
            self.samples.popleft()

    def clear(self) -> None:
        self.samples.clear()

    def pose_at(self, t: float, max_extrapolate_s: float) -> Optional[tuple[np.ndarray, bool, np.ndarray]]:
        """The epoch's dead-reckoned pose at t (interpolated; extrapolated a little past the newest), whether
        it slipped there, and the motion cut by the slip limit up to t (epoch frame)."""
        s = self.samples
        if len(s) < 2 or t < s[0].t:
            return None
        if t >= s[-1].t:
            if t - s[-1].t > max_extrapolate_s:
                return None
            a, b = s[-2], s[-1]
        else:
            lo, hi = 0, len(s) - 1
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if s[mid].t <= t:
                    lo = mid
                else:
                    hi = mid
            a, b = s[lo], s[hi]
        span = b.t - a.t
        w = (t - a.t) / span if span > 0 else 1.0
        pa, pb = np.array(a.pose), np.array(b.pose)
        step = pb - pa
        step[2] = wrap_angle(step[2])
        ca, cb = np.array(a.cut), np.array(b.cut)
        return pa + w * step, a.slip or b.slip, ca + min(w, 1.0) * (cb - ca)

    def delta(self, t0: float, t1: float, max_extrapolate_s: float) -> Optional[OdometryDelta]:
        p0 = self.pose_at(t0, max_extrapolate_s)
        p1 = self.pose_at(t1, max_extrapolate_s)
        if p0 is None or p1 is None:
            return None
        (a, slip0, cut0), (b, slip1, cut1) = p0, p1
        c, s = math.cos(a[2]), math.sin(a[2])
        d = b[:2] - a[:2]
        k = cut1 - cut0
        return OdometryDelta(dx=c * d[0] + s * d[1], dy=-s * d[0] + c * d[1], dyaw=wrap_angle(b[2] - a[2]),
                             slip=slip0 or slip1, cut_dx=c * k[0] + s * k[1], cut_dy=-s * k[0] + c * k[1])

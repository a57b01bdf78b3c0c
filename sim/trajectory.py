"""Trajectories of the simulated robot: pose (x, y, yaw) as a function of time.

- waypoints: a closed loop driven at constant speed; without given headings the robot turns in place
  (at the yaw rate) to face each leg, with headings it turns while driving (holonomic, like Robocon bases).
- random walk: random targets inside the court with random headings, deterministic for a seed.
- csv: a recorded pose CSV played back, one row per frame or by a time column.
"""
from __future__ import annotations

import bisect
import csv
import math
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np

from courtloc.sim.labels import orientation_z_to_yaw
from courtloc.world.angles import wrap_angle
from courtloc.world.court import Court

Pose = tuple[float, float, float]


class Trajectory(Protocol):
    def pose_at(self, t: float) -> Pose: ...


class _Legs:
    """Piecewise-linear motion: legs of (duration, start pose, end pose), yaw along the shortest turn."""

    def __init__(self) -> None:
        self.starts: list[float] = []
        self.legs: list[tuple[float, Pose, Pose]] = []
        self.total = 0.0

    def add(self, duration: float, a: Pose, b: Pose) -> None:
        if duration <= 0:
            return
        self.starts.append(self.total)
        self.legs.append((duration, a, b))
        self.total += duration

    def pose_at(self, t: float) -> Pose:
        i = max(0, bisect.bisect_right(self.starts, t) - 1)
        duration, a, b = self.legs[i]
        s = min(max((t - self.starts[i]) / duration, 0.0), 1.0)
        turn = wrap_angle(b[2] - a[2])
        return (a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), wrap_angle(a[2] + s * turn))


def _leg_to(legs: _Legs, here: Pose, target_xy: tuple[float, float], target_yaw: float | None,
            speed: float, yaw_rate: float) -> Pose:
    """Append the legs from `here` to the target; returns the pose reached."""
    dx, dy = target_xy[0] - here[0], target_xy[1] - here[1]
    dist = math.hypot(dx, dy)
    if target_yaw is None:
        heading = math.atan2(dy, dx) if dist > 1e-9 else here[2]
        turned = (here[0], here[1], heading)
        legs.add(abs(wrap_angle(heading - here[2])) / yaw_rate, here, turned)
        end = (target_xy[0], target_xy[1], heading)
        legs.add(dist / speed, turned, end)
        return end
    end = (target_xy[0], target_xy[1], wrap_angle(target_yaw))
    legs.add(max(dist / speed, abs(wrap_angle(target_yaw - here[2])) / yaw_rate), here, end)
    return end


class WaypointTrajectory:
    def __init__(self, waypoints: Sequence[Sequence[float]], speed: float, yaw_rate: float) -> None:
        if len(waypoints) < 2:
            raise ValueError("a waypoint trajectory needs at least 2 waypoints")
        if speed <= 0 or yaw_rate <= 0:
            raise ValueError("speed and yaw rate must be positive")
        points = [tuple(float(v) for v in w) for w in waypoints]
        if any(len(p) not in (2, 3) for p in points):
            raise ValueError("each waypoint is [x, y] or [x, y, yaw]")
        first = points[0]
        start_yaw = first[2] if len(first) == 3 else math.atan2(points[1][1] - first[1], points[1][0] - first[0])
        here: Pose = (first[0], first[1], start_yaw)
        self._legs = _Legs()
        for target in points[1:] + points[:1]:  # closed loop back to the start
            here = _leg_to(self._legs, here, (target[0], target[1]), target[2] if len(target) == 3 else None,
                           speed, yaw_rate)
        _leg_to(self._legs, here, (first[0], first[1]), start_yaw, speed, yaw_rate)
        if self._legs.total <= 0:
            raise ValueError("waypoints do not move the robot")

    def pose_at(self, t: float) -> Pose:
        return self._legs.pose_at(math.fmod(t, self._legs.total) if t >= 0 else 0.0)


class RandomWalkTrajectory:
    """Random targets uniformly inside the court (shrunk by `margin`), random headings; deterministic."""

    def __init__(self, court: Court, speed: float, yaw_rate: float, seed: int, margin: float = 0.3,
                 start: Pose | None = None) -> None:
        hx, hy = court.area_half_extent_m
        if hx <= margin or hy <= margin:
            raise ValueError(f"margin {margin} m leaves no room on court {court.name!r}")
        self._limits = (hx - margin, hy - margin)
        self._rng = np.random.default_rng(seed)
        self._speed, self._yaw_rate = speed, yaw_rate
        self._legs = _Legs()
        self._here: Pose = start if start is not None else (0.0, 0.0, 0.0)

    def pose_at(self, t: float) -> Pose:
        while self._legs.total <= t:
            target = (float(self._rng.uniform(-self._limits[0], self._limits[0])),
                      float(self._rng.uniform(-self._limits[1], self._limits[1])))
            yaw = float(self._rng.uniform(-math.pi, math.pi))
            self._here = _leg_to(self._legs, self._here, target, yaw, self._speed, self._yaw_rate)
        return self._legs.pose_at(max(t, 0.0))


class CsvTrajectory:
    """Poses from a CSV with x, y and either yaw (radians) or orientation_z (seed format).

    With a column t (seconds) poses are interpolated in time; otherwise row k is shown at k / fps.
    Playback loops.
    """

    def __init__(self, path: str | Path, fps: float) -> None:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"trajectory CSV {path} does not exist")
        with path.open(newline="") as handle:
            reader = csv.DictReader(handle)
            cols = reader.fieldnames or []
            if "x" not in cols or "y" not in cols or not ({"yaw", "orientation_z"} & set(cols)):
                raise ValueError(f"{path}: needs columns x, y and yaw or orientation_z; found {cols}")
            rows: list[tuple[float, float, float, float]] = []
            for line, row in enumerate(reader, start=2):
                try:
                    x, y = float(row["x"]), float(row["y"])
                    yaw = float(row["yaw"]) if "yaw" in cols else float(orientation_z_to_yaw(float(row["orientation_z"])))
                    t = float(row["t"]) if "t" in cols else (line - 2) / fps
                except (TypeError, ValueError) as exc:
                    raise ValueError(f"{path} line {line}: malformed row {row} ({exc})") from None
                if not all(math.isfinite(v) for v in (x, y, yaw, t)):
                    raise ValueError(f"{path} line {line}: non-finite value in {row}")
                if rows and t <= rows[-1][3]:
                    raise ValueError(f"{path} line {line}: time t={t} does not increase")
                rows.append((x, y, yaw, t))
        if not rows:
            raise ValueError(f"{path}: no poses")
        arr = np.array(rows)
        self.path = path
        self.poses = arr[:, :3]
        self.times = arr[:, 3] - arr[0, 3]
        self._yaw_unwrapped = np.unwrap(self.poses[:, 2])
        self._period = self.times[-1] + (1.0 / fps)

    def pose_at(self, t: float) -> Pose:
        t = math.fmod(max(t, 0.0), self._period)
        x = float(np.interp(t, self.times, self.poses[:, 0]))
        y = float(np.interp(t, self.times, self.poses[:, 1]))
        yaw = wrap_angle(float(np.interp(t, self.times, self._yaw_unwrapped)))
        return x, y, yaw


class KidnapTrajectory:
    """A trajectory whose robot is picked up and put down elsewhere (teleported) at given times.

    Before the first kidnap the robot follows `first`; after kidnap k it random-walks from a new pose drawn
    for (seed, k): at least `min_jump_m` from where it was, with |x| >= `min_abs_x_m`, and — with
    `same_half` — in the half it was in. A teleport into the other half of a point-symmetric court looks
    exactly like one to the mirror twin, so only the configured side could ever tell them apart.
    """

    def __init__(self, first: Trajectory, court: Court, times_s: Sequence[float], speed: float, yaw_rate: float,
                 seed: int, margin: float = 0.3, same_half: bool = True, min_jump_m: float = 1.5,
                 min_abs_x_m: float = 1.0) -> None:
        times = [float(t) for t in times_s]
        if any(t <= 0 for t in times) or times != sorted(set(times)):
            raise ValueError(f"kidnap times must be positive and increasing, got {list(times_s)}")
        hx, hy = court.area_half_extent_m
        if hx - margin <= min_abs_x_m:
            raise ValueError(f"court {court.name!r} has no room for a kidnap target with |x| >= {min_abs_x_m} m")
        self.times = times
        self.segments: list[Trajectory] = [first]
        for k, t in enumerate(times, start=1):
            before = self.segments[-1].pose_at(t - (self.times[k - 2] if k > 1 else 0.0))
            rng = np.random.default_rng([seed, k, 7])
            for _ in range(1000):
                x = float(rng.uniform(min_abs_x_m, hx - margin))
                side = (1.0 if before[0] >= 0 else -1.0) if same_half else float(rng.choice([-1.0, 1.0]))
                target = (side * x, float(rng.uniform(-hy + margin, hy - margin)),
                          float(rng.uniform(-math.pi, math.pi)))
                if math.hypot(target[0] - before[0], target[1] - before[1]) >= min_jump_m:
                    break
            else:  # pragma: no cover - a court this small has no room to jump
                raise ValueError(f"no kidnap target {min_jump_m} m away on court {court.name!r}")
            self.segments.append(RandomWalkTrajectory(court, speed, yaw_rate, seed * 1000 + k, margin, start=target))

    def pose_at(self, t: float) -> Pose:
        k = bisect.bisect_right(self.times, t)
        return self.segments[k].pose_at(t - (self.times[k - 1] if k else 0.0))

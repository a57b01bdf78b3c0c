"""Physics prior for the shooter: launch speed to reach the ring, then wheel RPM.

The ball leaves the release point at a fixed launch angle and must pass through the ring centre on
its way down. Drag is optional and quadratic: a = -g z_hat - k |v| v, with k = rho Cd A / (2 m) in 1/m
(about 0.02 for a size-7 basketball in still air). The ball's exit speed is `slip` times the wheel's
surface speed (about 0.5 for one wheel against a hood, up to ~0.9 for twin wheels), so
rpm = v / (slip * wheel_radius) * 60 / (2 pi).

The trajectory is integrated with horizontal distance as the variable (x only ever grows), which
turns "height at the ring" into a plain integral; the launch speed is the root (brentq) of
height-at-ring minus ring height, which rises monotonically with speed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

G = 9.81
_STEPS_PER_M = 10  # RK4 steps per metre of flight: height error ~1e-8 m against a 40-per-metre run


@dataclass(frozen=True)
class ShotModel:
    release_height_m: float = 0.9
    ring_height_m: float = 2.43
    launch_angle_deg: float = 60.0
    drag_per_m: float = 0.0
    wheel_radius_m: float = 0.05
    slip: float = 0.7


@dataclass(frozen=True)
class ShotSolve:
    speed_mps: float
    rpm: float
    entry_angle_deg: float  # below horizontal at the ring; >= ~32 deg for a size-7 ball to clear a 45 cm ring
    flight_time_s: float


class UnreachableShot(ValueError):
    """No launch speed at this angle brings the ball down through the ring at this distance."""


def _derivative(state: tuple[float, float, float, float], drag: float) -> tuple[float, float, float, float]:
    """d/dx of (z, vx, vz, t)."""
    _, vx, vz, _ = state
    speed = math.hypot(vx, vz)
    return (vz / vx, -drag * speed, (-G - drag * speed * vz) / vx, 1.0 / vx)


def fly_to(distance_m: float, speed_mps: float, model: ShotModel) -> tuple[float, float, float, float]:
    """(z, vx, vz, t) of the ball when it has travelled `distance_m` horizontally (classic RK4 in x)."""
    angle = math.radians(model.launch_angle_deg)
    state = (model.release_height_m, speed_mps * math.cos(angle), speed_mps * math.sin(angle), 0.0)
    steps = max(20, int(math.ceil(distance_m * _STEPS_PER_M)))
    h = distance_m / steps
    k = model.drag_per_m
    for _ in range(steps):
        k1 = _derivative(state, k)
        k2 = _derivative(tuple(s + 0.5 * h * d for s, d in zip(state, k1)), k)  # type: ignore[arg-type]
        k3 = _derivative(tuple(s + 0.5 * h * d for s, d in zip(state, k2)), k)  # type: ignore[arg-type]
        k4 = _derivative(tuple(s + h * d for s, d in zip(state, k3)), k)  # type: ignore[arg-type]
        state = tuple(s + h / 6.0 * (a + 2 * b + 2 * c + e)  # type: ignore[assignment]
                      for s, a, b, c, e in zip(state, k1, k2, k3, k4))
    return state


def vacuum_speed(distance_m: float, model: ShotModel) -> float:
    """Closed-form launch speed without drag (a lower bound for the speed with drag)."""
    angle = math.radians(model.launch_angle_deg)
    rise = model.ring_height_m - model.release_height_m
    clearance = distance_m * math.tan(angle) - rise
    if distance_m <= 0 or clearance <= 0:
        raise UnreachableShot(f"at {model.launch_angle_deg} deg the ring {distance_m:.2f} m away is above the launch line")
    return math.sqrt(G * distance_m ** 2 / (2.0 * math.cos(angle) ** 2 * clearance))


def rpm_for_speed(speed_mps: float, model: ShotModel) -> float:
    return speed_mps / (model.slip * model.wheel_radius_m) * 60.0 / (2.0 * math.pi)


def solve(distance_m: float, model: ShotModel) -> ShotSolve:
    """Launch speed and wheel RPM that put the ball through the ring centre `distance_m` away."""

    def miss(speed: float) -> float:
        return fly_to(distance_m, speed, model)[0] - model.ring_height_m

    low = vacuum_speed(distance_m, model)
    if model.drag_per_m <= 0.0:
        speed = low
    else:
        high = low * 1.25
        while miss(high) < 0.0:
            high *= 1.25
            if high > 100.0:
                raise UnreachableShot(f"drag {model.drag_per_m}/m: no speed below 100 m/s reaches {distance_m:.2f} m")
        from scipy.optimize import brentq  # scipy costs ~0.8 s to import: only a solve pays it, not every config reader

        speed = brentq(miss, low, high, xtol=1e-9, rtol=1e-12)
    _, vx, vz, t = fly_to(distance_m, speed, model)
    if vz >= 0.0:
        raise UnreachableShot(f"at {model.launch_angle_deg} deg the ball still rises at {distance_m:.2f} m")
    return ShotSolve(speed_mps=speed, rpm=rpm_for_speed(speed, model),
                     entry_angle_deg=math.degrees(math.atan2(-vz, vx)), flight_time_s=t)


def prior_table(model: ShotModel, distances_m: Sequence[float]) -> list[tuple[float, float]]:
    """(distance, rpm) of the prior at each reachable distance (unreachable ones are left out)."""
    rows = []
    for d in distances_m:
        try:
            rows.append((float(d), solve(float(d), model).rpm))
        except UnreachableShot:
            continue
    return rows


@dataclass(frozen=True)
class Fit:
    model: ShotModel
    rms_rpm: float
    max_rpm: float
    residuals_rpm: tuple[float, ...]


def fit(distances_m: Sequence[float], rpms: Sequence[float], base: ShotModel, fit_drag: bool = True,
        max_drag_per_m: float = 0.08) -> Fit:
    """Slip (and drag) of `base` that best explain a measured table, least squares in RPM.

    For a given drag the RPM is proportional to 1/slip, so slip has a closed form; drag is a bounded
    1-D search. The release height, ring height, angle and wheel radius stay as given.
    """

    d = np.asarray(distances_m, dtype=float)
    y = np.asarray(rpms, dtype=float)
    if d.size < 2:
        raise ValueError("fit needs at least two table rows")

    def best_slip(drag: float) -> tuple[float, np.ndarray]:
        speeds = np.array([solve(float(x), replace(base, drag_per_m=drag)).speed_mps for x in d])
        per_speed = speeds / (base.wheel_radius_m) * 60.0 / (2.0 * math.pi)  # rpm at slip = 1
        scale = float(per_speed @ y / (per_speed @ per_speed))  # least-squares 1/slip
        return 1.0 / scale, y - scale * per_speed

    if fit_drag:
        from scipy.optimize import minimize_scalar  # see solve(): imported where used

        result = minimize_scalar(lambda k: float(np.sqrt(np.mean(best_slip(k)[1] ** 2))),
                                 bounds=(0.0, max_drag_per_m), method="bounded", options={"xatol": 1e-5})
        drag = float(result.x)
    else:
        drag = base.drag_per_m
    slip, residuals = best_slip(drag)
    model = replace(base, drag_per_m=drag, slip=slip)
    return Fit(model=model, rms_rpm=float(np.sqrt(np.mean(residuals ** 2))),
               max_rpm=float(np.max(np.abs(residuals))), residuals_rpm=tuple(float(r) for r in residuals))

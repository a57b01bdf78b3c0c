"""Robust Gauss-Newton fit of a 2D rigid pose (x, y, yaw) to the court's signed distance field.

Each hit's residual is the field value at the hit's court position, divided by the floor error one
image pixel causes in the edge-normal direction (long-range hits are weak along the view, so they must
not outvote near ones). Weights: Huber for the first iterations (wide basin), then Tukey (outliers such
as unmodelled white objects get zero weight). Hits where the scan ray enters paint instead of leaving it
cannot be far edges and are gated out.

Optionally (FitConfig.tilt_sigma_deg > 0) the fit also estimates the body's pitch and roll for the frame,
with a Gaussian prior around zero: a robot rocks when it accelerates, and 0.1 degree of pitch moves a
hit 10 m away by ~30 cm along the view, which a rigid 2D fit can only absorb by a wrong yaw/position.
Pitch changes every hit's angle below the horizon by the same amount, roll by tan(azimuth) times it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from courtloc.localizer.config import FitConfig, QualityConfig
from courtloc.localizer.court_field import CourtField
from courtloc.localizer.projection import ProjectedHits


@dataclass(frozen=True)
class FitResult:
    pose: np.ndarray  # (3,) x, y, yaw (rad, wrapped to (-pi, pi])
    cost: float  # mean robust loss over all hits (lower is better; comparable between candidates)
    n_hits: int
    n_inliers: int
    inlier_ratio: float
    rms_m: float  # RMS metric residual of the inliers
    position_std_m: float  # worst-direction position std from the normal matrix
    yaw_std_rad: float
    valid: bool
    quality: float  # 0..1
    tilt: tuple[float, float] = (0.0, 0.0)  # estimated (pitch, roll) of the body, rad


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _residuals(field: CourtField, hits: ProjectedHits, params: np.ndarray, cfg: FitConfig):
    """Per hit: residual d (m), its Jacobian rows (x, y, yaw, pitch, roll) / sigma, sigma, usable mask.

    2D vectors are complex numbers here: a frame of ~100 hits is small enough that numpy's per-call
    overhead, not arithmetic, sets the speed, and complex math halves the number of calls.
    """
    x, y, yaw, pitch, roll = params
    rot = complex(math.cos(yaw), math.sin(yaw))
    if pitch or roll:
        dep = np.maximum(hits.depression + pitch + roll * hits.tan_azimuth, 1e-3)
        rng = hits.camera_height / np.tan(dep)
        local = hits.camera_xy + hits.cview * rng
    else:
        dep = hits.depression
        local = hits.cpoints
    r = local * rot
    d, gx, gy = field.lookup(r.real + x, r.imag + y)
    n = gx + 1j * gy
    n /= np.abs(n) + 1e-9
    view_w = hits.cview * rot
    # Edge normal against the hit's view direction splits the pixel error into along/across parts.
    q = n * np.conj(view_w)
    sig2 = (q.real * hits.sigma[:, 0]) ** 2 + (q.imag * hits.sigma[:, 1]) ** 2
    floor = cfg.floor_sigma_m + cfg.range_sigma * hits.range_m if cfg.range_sigma else cfg.floor_sigma_m
    sig = np.sqrt(sig2 * cfg.pixel_sigma**2 + floor * floor)
    ray_cos = (n * np.conj(hits.cray * rot)).real
    inside = d < 0
    # Inside paint but nearer the edge the ray entered by: the hit belongs to the band's far edge,
    # (2 * half-width - depth) further along, so measure to that edge (gradient flips with it).
    flip = inside & (ray_cos < 0)
    if field.half_width is not None and flip.any():
        hw = field.nearest(r.real[flip] + x, r.imag[flip] + y, field.half_width)
        d[flip] = -d[flip] - 2.0 * hw
        sign = np.where(flip, -1.0, 1.0)
        gx = gx * sign
        gy = gy * sign
    usable = (inside | (ray_cos >= cfg.gate_cos)) & (np.abs(d) < cfg.max_residual_m)
    inv = 1.0 / sig
    j = np.empty((5, len(d)))
    np.multiply(gx, inv, out=j[0])
    np.multiply(gy, inv, out=j[1])
    np.multiply(gy * r.real - gx * r.imag, inv, out=j[2])
    # d(point)/d(depression) = -h / sin^2(dep) along the view; roll scales that by tan(azimuth).
    s = np.sin(dep)
    along = (gx * view_w.real + gy * view_w.imag) * (-hits.camera_height / (s * s)) * inv
    j[3] = along
    np.multiply(along, hits.tan_azimuth, out=j[4])
    return d, j, sig, usable


def _tukey_weight(z: np.ndarray, c: float) -> np.ndarray:
    u = np.maximum(1.0 - (z / c) ** 2, 0.0)
    return u * u


def _tukey_loss(z: np.ndarray, c: float) -> np.ndarray:
    u = np.maximum(1.0 - (z / c) ** 2, 0.0)
    return (c * c / 6.0) * (1.0 - u**3)


def fit_pose(field: CourtField, hits: ProjectedHits, start: np.ndarray, cfg: FitConfig,
             quality: QualityConfig, iterations: int | None = None) -> FitResult:
    """Refine `start` (x, y, yaw) by IRLS; the result carries its quality assessment."""
    params = np.zeros(5)
    params[:3] = np.asarray(start, np.float64)[:3]
    n = len(hits.points)
    if n < 3:
        return _result(params, np.inf, n, 0, 0.0, np.inf, np.inf, np.inf, quality)
    k = 5 if cfg.tilt_sigma_deg > 0 else 3
    prior = np.zeros(5)
    if k == 5:
        prior[3:] = 1.0 / math.radians(cfg.tilt_sigma_deg) ** 2
    max_it = iterations or cfg.max_iterations
    converged = False
    for it in range(max_it + 1):
        d, j, sig, usable = _residuals(field, hits, params, cfg)
        z = d / sig
        if converged or it == max_it:
            break  # these residuals, at the final pose, feed the quality assessment below
        if it < cfg.huber_iterations:
            w = np.minimum(1.0, cfg.huber_c / np.maximum(np.abs(z), 1e-9))
        else:
            w = _tukey_weight(z, cfg.tukey_c)
        w *= usable
        jk = j[:k]
        jw = jk * w
        h = jw @ jk.T + np.diag(prior[:k])
        g = jw @ z + prior[:k] * params[:k]
        if h[0, 0] + h[1, 1] <= 0.0:
            break
        # Tiny damping keeps a degenerate (parallel lines only) system solvable; quality reports it.
        step = -np.linalg.solve(h + np.eye(k) * (1e-6 * np.trace(h[:3, :3]) + 1e-12), g)
        params[:k] += step
        params[2] = wrap(params[2])
        converged = math.hypot(step[0], step[1]) < cfg.step_tol_m and abs(step[2]) < cfg.step_tol_m / 5.0
    inl = usable & (np.abs(z) < quality.inlier_sigmas)
    n_in = int(np.count_nonzero(inl))
    loss = np.where(usable, _tukey_loss(z, cfg.tukey_c), cfg.tukey_c**2 / 6.0)
    cost = float(loss.mean())
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if n_in else np.inf
    # Covariance of the normal matrix with the inliers at unit weight (units: pixel_sigma noise);
    # with tilt estimated, its uncertainty is included (marginalised) in the pose block.
    ji = j[:k, inl]
    hh = ji @ ji.T + np.diag(prior[:k])
    try:
        cov = np.linalg.inv(hh + np.eye(k) * 1e-12)
        a, b, c = cov[0, 0], cov[0, 1], cov[1, 1]
        worst = 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))  # larger 2x2 eigenvalue
        pos_std = math.sqrt(max(worst, 0.0))
        yaw_std = math.sqrt(max(cov[2, 2], 0.0))
    except np.linalg.LinAlgError:
        pos_std = yaw_std = np.inf
    return _result(params, cost, n, n_in, n_in / max(n, 1), rms, pos_std, yaw_std, quality)


def _result(params: np.ndarray, cost: float, n: int, n_in: int, ratio: float, rms: float, pos_std: float,
            yaw_std: float, q: QualityConfig) -> FitResult:
    valid = (n_in >= q.min_inliers and ratio >= q.min_inlier_ratio and pos_std <= q.max_position_std_m
             and yaw_std <= math.radians(q.max_yaw_std_deg))
    if not np.isfinite(pos_std) or not np.isfinite(yaw_std):
        score = 0.0
    else:
        score = (min(1.0, n_in / (2.0 * q.min_inliers)) * min(1.0, ratio / max(q.min_inlier_ratio, 1e-9) * 0.5 + 0.5)
                 * math.exp(-pos_std / q.max_position_std_m) * math.exp(-math.degrees(yaw_std) / q.max_yaw_std_deg))
        score = score if valid else min(score, 0.49)
    return FitResult(pose=params[:3].copy(), cost=cost, n_hits=n, n_inliers=n_in, inlier_ratio=ratio, rms_m=rms,
                     position_std_m=pos_std, yaw_std_rad=yaw_std, valid=bool(valid), quality=float(score),
                     tilt=(float(params[3]), float(params[4])))

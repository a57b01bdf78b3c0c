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
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from courtloc.localizer import band_bias, fit_kernel
from courtloc.localizer.config import FitConfig, QualityConfig
from courtloc.localizer.court_field import CourtField
from courtloc.localizer.projection import ProjectedHits
from courtloc.world.angles import wrap_angle

# The compiled kernels (fit_kernel.c here, search_kernel.c for the global search) when they were built; the
# numpy code is the reference they are tested against and the fallback without a compiler. A context variable,
# so that switching them for a comparison (tests, `courtloc bench localize`) does not leak into other threads.
_use_kernel: ContextVar[bool] = ContextVar("courtloc_fit_kernel", default=True)


def kernels_wanted() -> bool:
    """Whether this context asks for the compiled kernels (`kernel_enabled`), built or not."""
    return _use_kernel.get()


def kernel_active() -> bool:
    """Whether fit_poses (and the predictor's hits -> geometry step) run compiled in this context."""
    return fit_kernel.available() and kernels_wanted()


@contextmanager
def kernel_enabled(enabled: bool) -> Iterator[bool]:
    """Within the block fit_poses and the global search use the compiled kernels (if built) or numpy; yields
    kernel_active() (the fit's)."""
    token = _use_kernel.set(enabled)
    try:
        yield kernel_active()
    finally:
        _use_kernel.reset(token)


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
    # (3, 3) covariance of (x, y, yaw), m^2 / m rad / rad^2, from the normal matrix behind the stds
    # (inliers at unit weight, i.e. hit noise as configured; tilt marginalised); None without a fit.
    covariance: np.ndarray | None = None
    # A valid fit a track demoted for landing farther from its prediction than `track_max_jump_m`.
    beyond_jump: bool = False


class FrameTerms:
    """Per-frame constants of the residual model, computed once and shared by every start and iteration."""

    def __init__(self, hits: ProjectedHits, cfg: FitConfig) -> None:
        self.hits = hits
        # Pixel noise folded into the per-hit floor errors (along the view, across it).
        self.sig_along = hits.sigma[:, 0] * cfg.pixel_sigma
        self.sig_across = hits.sigma[:, 1] * cfg.pixel_sigma
        floor = cfg.floor_sigma_m + cfg.range_sigma * hits.range_m if cfg.range_sigma else cfg.floor_sigma_m
        self.floor2 = floor * floor
        s = np.sin(hits.depression)
        # d(point)/d(depression) = -h / sin^2(dep) along the view (at zero tilt).
        self.dpoint_ddep = -hits.camera_height / (s * s)


def frame_residuals(field: CourtField, terms: FrameTerms, params: np.ndarray, cfg: FitConfig, tilt: bool):
    """For S poses at once (params (S, 5)): residual d (S, N) metres, a (S, 6, N) array holding the
    Jacobian rows (x, y, yaw, pitch, roll) / sigma and, as row 5, the normalised residual z = d / sigma
    (one matmul then gives both the normal matrix and the gradient), and the usable mask (S, N).

    Every start of a frame is evaluated in the same numpy calls: with ~100 hits numpy's per-call
    overhead, not arithmetic, sets the speed, so three starts cost little more than one. 2D vectors are
    complex numbers for the same reason (one call per rotation).
    """
    hits = terms.hits
    rot = np.exp(1j * params[:, 2])[:, None]
    if tilt and params[:, 3:].any():
        dep = np.maximum(hits.depression + params[:, 3:4] + params[:, 4:5] * hits.tan_azimuth, 1e-3)
        local = hits.camera_xy + hits.cview * (hits.camera_height / np.tan(dep))
        s = np.sin(dep)
        dpoint_ddep = -hits.camera_height / (s * s)
    else:
        local = hits.cpoints
        dpoint_ddep = terms.dpoint_ddep
    # Court positions in field-grid units (columns, rows): saves converting metres on every lookup.
    inv_res = 1.0 / field.resolution
    rg = local * (rot * inv_res)
    fx = rg.real + (params[:, 0:1] - field.x0) * inv_res
    fy = rg.imag + (params[:, 1:2] - field.y0) * inv_res
    d, gx, gy, cell = field.lookup_grid(fx, fy)  # gradient per grid cell
    norm = np.hypot(gx, gy)
    norm += 1e-12
    nx = gx / norm
    ny = gy / norm
    view_w = hits.cview * rot
    vx, vy = view_w.real, view_w.imag
    # Edge normal against the hit's view direction splits the pixel error into along/across parts.
    q_along = nx * vx + ny * vy
    q_across = ny * vx - nx * vy
    sig2 = (q_along * terms.sig_along) ** 2 + (q_across * terms.sig_across) ** 2
    sig2 += terms.floor2
    inv = 1.0 / np.sqrt(sig2)
    ray_w = hits.cray * rot
    ray_cos = nx * ray_w.real + ny * ray_w.imag
    inside = d < 0
    # Inside paint but nearer the edge the ray entered by: the hit belongs to the band's far edge,
    # (2 * half-width - depth) further along, so measure to that edge (gradient flips with it).
    flip = inside & (ray_cos < 0)
    any_flip = bool(flip.any())
    half = cell.nearest(field.half_width) if field.half_width is not None and (any_flip or cfg.band_bias_widths) \
        else None
    if half is not None and any_flip:
        # Whole arrays, not the flipped subset: boolean indexing costs more calls than it saves.
        d = np.where(flip, -d - 2.0 * half, d)
        sign = 1.0 - 2.0 * flip
        gx = gx * sign
        gy = gy * sign
    if half is not None and cfg.band_bias_widths:
        d = d - band_bias.offset_m(half, hits.step_m * np.abs(ray_cos), cfg)
    usable = (inside | (ray_cos >= cfg.gate_cos)) & (np.abs(d) < cfg.max_residual_m)
    inv_m = inv * inv_res  # 1/sigma and per-cell -> per-metre gradient in one factor
    j = np.empty((params.shape[0], 6, d.shape[1]))
    np.multiply(gx, inv_m, out=j[:, 0])
    np.multiply(gy, inv_m, out=j[:, 1])
    # Grid-unit gradient times grid-unit lever arm = metric gradient times metric lever arm.
    np.multiply(gy * rg.real - gx * rg.imag, inv, out=j[:, 2])
    along = (gx * vx + gy * vy) * dpoint_ddep * inv_m
    j[:, 3] = along
    # Roll changes the depression by tan(azimuth) times itself.
    np.multiply(along, hits.tan_azimuth, out=j[:, 4])
    np.multiply(d, inv, out=j[:, 5])
    return d, j, usable


def _tukey_weight(z: np.ndarray, c: float) -> np.ndarray:
    u = np.maximum(1.0 - (z / c) ** 2, 0.0)
    return u * u


def _tukey_loss(z: np.ndarray, c: float) -> np.ndarray:
    u = np.maximum(1.0 - (z / c) ** 2, 0.0)
    return (c * c / 6.0) * (1.0 - u**3)


def fit_pose(field: CourtField, hits: ProjectedHits, start: np.ndarray, cfg: FitConfig,
             quality: QualityConfig, iterations: int | None = None) -> FitResult:
    """Refine `start` (x, y, yaw) by IRLS; the result carries its quality assessment."""
    return fit_poses(field, hits, np.asarray(start, np.float64)[None, :3], cfg, quality, iterations)[0]


def fit_poses(field: CourtField, hits: ProjectedHits, starts: np.ndarray, cfg: FitConfig,
              quality: QualityConfig, iterations: int | None = None) -> list[FitResult]:
    """Refine each of `starts` (S, 3) independently by IRLS, all in one call of the compiled kernel (or,
    without it, in the same numpy calls).

    Each start stops on its own once its step is below tolerance (its pose is then frozen), so every
    result equals what a fit from that start alone would give.
    """
    starts = np.atleast_2d(np.asarray(starts, np.float64))
    n_starts = starts.shape[0]
    n = len(hits)
    if n < 3:
        return [_result(s[:3].copy(), (0.0, 0.0), np.inf, n, 0, 0.0, np.inf, np.inf, np.inf, quality)
                for s in starts]
    max_it = iterations or cfg.max_iterations
    kfield = _kernel_field(field)
    if kfield is None:
        return _fit_poses_numpy(field, hits, starts, cfg, quality, max_it)
    out = fit_kernel.run(kfield, hits, starts[:, :3], cfg, quality.inlier_sigmas, max_it)
    poses = out[:, :3].copy()
    covs = out[:, fit_kernel.COV].reshape(n_starts, 3, 3)
    results = []
    # Plain floats from here: numpy scalars would cost more than the arithmetic.
    for s, (_, _, _, pitch, roll, cost, n_in, rms, pos_std, yaw_std, *_, cov_ok) in enumerate(out.tolist()):
        n_in = int(n_in)
        results.append(_result(poses[s], (pitch, roll), cost, n, n_in, n_in / n, rms, pos_std, yaw_std, quality,
                               covs[s].copy() if cov_ok else None))
    return results


def _kernel_field(field: CourtField):
    """The kernel's view of `field`, or None for the numpy path (disabled, not built, unusable field)."""
    if not kernel_active():  # fit_kernel said once, at import, when it was not built
        return None
    return fit_kernel.kernel_field(field)


def _fit_poses_numpy(field: CourtField, hits: ProjectedHits, starts: np.ndarray, cfg: FitConfig,
                     quality: QualityConfig, max_it: int) -> list[FitResult]:
    """fit_poses in numpy: the reference implementation (and the fallback without the compiled kernel)."""
    n_starts = starts.shape[0]
    params = np.zeros((n_starts, 5))
    params[:, :3] = starts[:, :3]
    n = len(hits)
    tilt = cfg.tilt_sigma_deg > 0
    k = 5 if tilt else 3
    prior = np.zeros(5)
    if tilt:
        prior[3:] = 1.0 / math.radians(cfg.tilt_sigma_deg) ** 2
    prior_k = prior[:k]
    eye = np.eye(k)
    prior_diag = np.diag(prior_k)
    terms = FrameTerms(hits, cfg)
    rows = np.r_[0:k, 5]  # the estimated parameters' Jacobian rows and z
    done = np.zeros(n_starts, bool)
    for it in range(max_it + 1):
        d, j, usable = frame_residuals(field, terms, params, cfg, tilt)
        z = j[:, 5]
        if done.all() or it == max_it:
            break  # these residuals, at the final poses, feed the quality assessment below
        if it < cfg.huber_iterations:
            w = np.minimum(1.0, cfg.huber_c / np.maximum(np.abs(z), 1e-9))
        else:
            w = _tukey_weight(z, cfg.tukey_c)
        w *= usable
        jz = j if k == 5 else j[:, rows]
        m = (jz * w[:, None, :]) @ jz.transpose(0, 2, 1)
        h = m[:, :k, :k] + prior_diag
        g = m[:, :k, k] + prior_k * params[:, :k]
        done |= h[:, 0, 0] + h[:, 1, 1] <= 0.0
        # Tiny damping keeps a degenerate (parallel lines only) system solvable; quality reports it.
        damp = 1e-6 * (h[:, 0, 0] + h[:, 1, 1] + h[:, 2, 2]) + 1e-12
        step = -np.linalg.solve(h + damp[:, None, None] * eye, g[:, :, None])[:, :, 0]
        step[done] = 0.0
        params[:, :k] += step
        params[:, 2] = wrap_angle(params[:, 2])
        done |= (np.hypot(step[:, 0], step[:, 1]) < cfg.step_tol_m) & (np.abs(step[:, 2]) < cfg.step_tol_m / 5.0)
    inl = usable & (np.abs(z) < quality.inlier_sigmas)
    n_in = np.count_nonzero(inl, axis=1)
    loss = np.where(usable, _tukey_loss(z, cfg.tukey_c), cfg.tukey_c**2 / 6.0)
    cost = loss.mean(axis=1)
    rms = np.sqrt(np.sum(d * d * inl, axis=1) / np.maximum(n_in, 1))
    # Covariance of the normal matrix with the inliers at unit weight (units: pixel_sigma noise);
    # with tilt estimated, its uncertainty is included (marginalised) in the pose block.
    jk = j[:, :k]
    hh = (jk * inl[:, None, :]) @ jk.transpose(0, 2, 1) + (prior_diag + eye * 1e-12)
    stds = _pose_stds(hh)
    return [_result(params[s, :3].copy(), (float(params[s, 3]), float(params[s, 4])), float(cost[s]), n,
                    int(n_in[s]), int(n_in[s]) / max(n, 1), float(rms[s]) if n_in[s] else np.inf, stds[s][0],
                    stds[s][1], quality, stds[s][2])
            for s in range(n_starts)]


def _pose_stds(hh: np.ndarray) -> list[tuple[float, float, np.ndarray | None]]:
    """(worst-direction position std, yaw std, (3, 3) pose covariance) per (k, k) normal matrix of the
    (S, k, k) stack; the pose block of the inverse is the covariance with tilt marginalised."""
    try:
        covs = np.linalg.inv(hh)
    except np.linalg.LinAlgError:  # one singular matrix fails the whole stack: invert one by one
        covs = []
        for m in hh:
            try:
                covs.append(np.linalg.inv(m))
            except np.linalg.LinAlgError:
                covs.append(None)
    out = []
    for cov in covs:
        if cov is None:
            out.append((np.inf, np.inf, None))
            continue
        a, b, c = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
        worst = 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))  # larger 2x2 eigenvalue
        out.append((math.sqrt(max(worst, 0.0)), math.sqrt(max(float(cov[2, 2]), 0.0)), np.array(cov[:3, :3])))
    return out


def quality_score(n_in: int, ratio: float, pos_std: float, yaw_std: float, valid: bool, q: QualityConfig) -> float:
    """0..1 from the inliers and the stds (the fit's, or a fused answer's posterior); below 0.5 when not valid."""
    if not math.isfinite(pos_std) or not math.isfinite(yaw_std):
        return 0.0
    score = (min(1.0, n_in / (2.0 * q.min_inliers)) * min(1.0, ratio / max(q.min_inlier_ratio, 1e-9) * 0.5 + 0.5)
             * math.exp(-pos_std / q.max_position_std_m) * math.exp(-math.degrees(yaw_std) / q.max_yaw_std_deg))
    return float(score if valid else min(score, 0.49))


def _result(pose: np.ndarray, tilt: tuple[float, float], cost: float, n: int, n_in: int, ratio: float, rms: float,
            pos_std: float, yaw_std: float, q: QualityConfig, covariance: np.ndarray | None = None) -> FitResult:
    valid = (n_in >= q.min_inliers and ratio >= q.min_inlier_ratio and pos_std <= q.max_position_std_m
             and yaw_std <= math.radians(q.max_yaw_std_deg))
    score = quality_score(n_in, ratio, pos_std, yaw_std, valid, q)
    return FitResult(pose=pose, cost=cost, n_hits=n, n_inliers=n_in, inlier_ratio=ratio, rms_m=rms,
                     position_std_m=pos_std, yaw_std_rad=yaw_std, valid=bool(valid), quality=float(score),
                     tilt=tilt, covariance=covariance)

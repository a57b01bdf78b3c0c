"""Motion model of the tracker: a constant-velocity Kalman filter on (x, y, yaw, vx, vy, yaw rate).

Why: a frame's fit is precise across the lines it sees and weak along them (its 3x3 covariance says
which way), and its errors persist for several frames while the view stays the same. The filter
predicts each frame from the past ones (the start pose of the fit: fewer wrong basins after a turn)
and fuses the fit with that prediction by their covariances, so in a frame's weak direction the
prediction dominates and in its strong directions the fit does.

Everything here is a pure function of the state the caller passes in (`MotionState`), like the rest of
the localizer: the caller keeps the state between frames (`GeometricLocalizer.track`). Causal: a state
only ever holds past frames. The rules, explicit:
- no state -> the frame is a global search; a valid answer starts a state, velocity unknown;
- a fit that is valid or trackable and agrees with the prediction (innovation chi-square, 3 dof, at
  most `gate_chi2`) updates the state; a degenerate fit's huge covariance in its free direction leaves
  that direction to the prediction;
- a valid fit that disagrees restarts the state at the fit (the fit is the evidence; a filter that is
  wrong would otherwise never let go), answered invalid (`jump`): the next frame must agree with it; a
  trackable but invalid one that disagrees is ignored;
- a state known worse than `regain_std_m` (after coasting or degenerate views), or carried by the
  constant-velocity model through `regain_weak_frames` frames in a row without a fit valid on its own,
  answers its next such fit invalid (`confirming`): one fit re-anchors it, two agreeing frames make it
  valid again; a trackable fit does not re-anchor it (along the lines it sees, the posterior is the
  prediction that drifted) and answers invalid;
- a frame without a usable fit answers the prediction (invalid) and counts as lost; after
  `max_lost_frames` lost frames in a row, a gap over `max_gap_s`, or once the state's position std
  passes `max_track_std_m`, the track is dropped and the caller acquires again with the lost state's
  pose as a prior (acquire.py).
The velocity decays with `velocity_tau_s` in the prediction: a robot that stops while the view is
degenerate must not be extrapolated on along the free direction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from courtloc.localizer.config import MotionConfig
from courtloc.world.angles import wrap_angle


@dataclass(frozen=True)
class MotionState:
    mean: np.ndarray  # (6,) x, y m, yaw rad (wrapped), vx, vy m/s, yaw rate rad/s
    cov: np.ndarray  # (6, 6)
    t: float | None  # time of `mean` in seconds (None: frames without times, cfg.frame_period_s apart)
    lost: int = 0  # frames in a row without a usable fit
    # Frames in a row answered without a valid fit (coasting, or degenerate views only) while the constant-
    # velocity model carried the track; a state odometry carried starts it anew (odometry_fusion).
    weak: int = 0

    @property
    def pose(self) -> np.ndarray:
        return self.mean[:3].copy()

    @property
    def position_std_m(self) -> float:
        """Worst-direction position std of the state."""
        a, b, d = float(self.cov[0, 0]), float(self.cov[0, 1]), float(self.cov[1, 1])
        # The larger eigenvalue of the 2x2 block in closed form: read several times a frame, and numpy's
        # eigvalsh (7 us a call idle, more under load) was a seventh of the infer stage's time in a profile of the
        # running chain.
        return math.sqrt(max(0.5 * (a + d) + math.hypot(0.5 * (a - d), b), 0.0))


def measurement_cov(fit_cov: np.ndarray | None, cfg: MotionConfig) -> np.ndarray | None:
    """The fit's (x, y, yaw) covariance as the filter's measurement noise: scaled (the fit's model
    assumes independent pixel noise, while its real errors are larger and shared by neighbouring hits)
    plus a floor (court model and label-free systematic errors)."""
    if fit_cov is None or not np.all(np.isfinite(fit_cov)):
        return None
    r = cfg.measurement_scale ** 2 * np.asarray(fit_cov, np.float64)
    r = 0.5 * (r + r.T)
    r[0, 0] += cfg.floor_position_m ** 2
    r[1, 1] += cfg.floor_position_m ** 2
    r[2, 2] += math.radians(cfg.floor_yaw_deg) ** 2
    return r


def start(pose: np.ndarray, fit_cov: np.ndarray | None, t: float | None, cfg: MotionConfig) -> MotionState:
    """A new state at a pose, its velocity unknown (`initial_speed_mps`, `initial_yaw_rate_dps` std)."""
    cov = np.zeros((6, 6))
    r = measurement_cov(fit_cov, cfg)
    cov[:3, :3] = r if r is not None else np.diag([0.1, 0.1, math.radians(2.0)]) ** 2
    cov[3, 3] = cov[4, 4] = cfg.initial_speed_mps ** 2
    cov[5, 5] = math.radians(cfg.initial_yaw_rate_dps) ** 2
    mean = np.zeros(6)
    mean[:3] = pose
    mean[2] = wrap_angle(mean[2])
    return MotionState(mean=mean, cov=cov, t=t, lost=0)


def mirrored(state: MotionState) -> MotionState:
    """The state's twin under the court's point symmetry: (x, y, yaw) -> (-x, -y, yaw + pi), velocities too."""
    flip = np.array([-1.0, -1.0, 1.0, -1.0, -1.0, 1.0])
    mean = state.mean * flip
    mean[2] = wrap_angle(mean[2] + math.pi)
    return MotionState(mean=mean, cov=state.cov * np.outer(flip, flip), t=state.t, lost=state.lost, weak=state.weak)


def at_frame(state: MotionState, t: float | None) -> bool:
    """Whether the state is already at the frame's time t: odometry carried it there (the constant-velocity model
    predicts only a state from before the frame)."""
    return t is not None and state.t is not None and state.t >= t


def elapsed(state: MotionState, t: float | None, cfg: MotionConfig) -> float:
    if t is None or state.t is None:
        return cfg.frame_period_s
    return max(t - state.t, 0.0)


def predict(state: MotionState, t: float | None, cfg: MotionConfig) -> MotionState:
    """The state advanced to time t at constant velocity; white-noise acceleration widens it."""
    dt = elapsed(state, t, cfg)
    f = np.eye(6)
    f[0, 3] = f[1, 4] = f[2, 5] = dt
    if cfg.velocity_tau_s > 0:
        # The velocity relaxes towards zero (a stopping robot is not extrapolated on); the position
        # integrates the decaying velocity. The process noise keeps the constant-velocity form.
        decay = math.exp(-dt / cfg.velocity_tau_s)
        f[0, 3] = f[1, 4] = f[2, 5] = cfg.velocity_tau_s * (1 - decay)
        f[3, 3] = f[4, 4] = f[5, 5] = decay
    mean = f @ state.mean
    mean[2] = wrap_angle(mean[2])
    q = np.zeros((6, 6))
    for i, sigma in ((0, cfg.accel_sigma_mps2), (1, cfg.accel_sigma_mps2), (2, math.radians(cfg.yaw_accel_sigma_dps2))):
        s2 = sigma * sigma
        # Spectral density s2 of the acceleration over dt: the standard continuous white-noise terms.
        q[i, i] = s2 * dt ** 3 / 3.0
        q[i, i + 3] = q[i + 3, i] = s2 * dt ** 2 / 2.0
        q[i + 3, i + 3] = s2 * dt
    cov = f @ state.cov @ f.T + q
    return MotionState(mean=mean, cov=cov, t=t, lost=state.lost, weak=state.weak)


def _inverse3(m: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by cofactors: at this size np.linalg.solve's per-call overhead (~20 us) is
    most of a tracked frame's filter time."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    cof = (e * i - f * h, c * h - b * i, b * f - c * e, f * g - d * i, a * i - c * g, c * d - a * f,
           d * h - e * g, b * g - a * h, a * e - b * d)
    det = a * cof[0] + b * cof[3] + c * cof[6]
    if det == 0.0 or not math.isfinite(det):
        raise np.linalg.LinAlgError("singular innovation covariance")
    return np.array(cof).reshape(3, 3) / det


@dataclass(frozen=True)
class Innovation:
    nu: np.ndarray  # (3,) measured minus predicted (x, y, yaw), yaw wrapped
    s_inv: np.ndarray  # (3, 3) inverse of its covariance
    chi2: float


def innovation(state: MotionState, pose: np.ndarray, r: np.ndarray) -> Innovation:
    """The measured pose against a predicted state: residual, inverse covariance, chi-square."""
    nu = np.asarray(pose, np.float64)[:3] - state.mean[:3]
    nu[2] = wrap_angle(nu[2])
    s_inv = _inverse3(state.cov[:3, :3] + r)
    return Innovation(nu=nu, s_inv=s_inv, chi2=float(nu @ s_inv @ nu))


def update(state: MotionState, pose: np.ndarray, r: np.ndarray, innov: Innovation | None = None) -> MotionState:
    """Kalman update with a measured (x, y, yaw) of covariance r (Joseph form: stays symmetric PSD);
    `innov`: the pose's innovation when the caller has it already (the gate computes it)."""
    innov = innov or innovation(state, pose, r)
    gain = state.cov[:, :3] @ innov.s_inv  # P H^T S^-1, H = [I 0]
    mean = state.mean + gain @ innov.nu
    mean[2] = wrap_angle(mean[2])
    ikh = np.eye(6)
    ikh[:, :3] -= gain
    cov = ikh @ state.cov @ ikh.T + gain @ r @ gain.T
    return MotionState(mean=mean, cov=0.5 * (cov + cov.T), t=state.t, lost=0)


def coast(state: MotionState, cfg: MotionConfig) -> MotionState:
    """A frame without a usable fit: keep the prediction, count the frame as lost."""
    return MotionState(mean=state.mean, cov=state.cov, t=state.t, lost=state.lost + 1, weak=state.weak + 1)


def is_lost(state: MotionState, t: float | None, cfg: MotionConfig) -> bool:
    """Too many frames without a usable fit, too long a gap, or a position known worse than
    `max_track_std_m` (degenerate views ridden too long: parallel lines 1.85 m apart let such a track snap
    to the wrong one, and the next valid fit near it would be fused as if the track were right): the
    caller acquires again, the state's pose as a prior (acquire.py)."""
    return (state.lost >= cfg.max_lost_frames or elapsed(state, t, cfg) > cfg.max_gap_s
            or state.position_std_m > cfg.max_track_std_m)


def pose_covariance(state: object) -> list[float]:
    """Row-major 3x3 (x, y, yaw) covariance of a motion state, [] when there is none."""
    if not isinstance(state, MotionState):
        return []
    return [float(v) for v in np.asarray(state.cov[:3, :3]).ravel()]

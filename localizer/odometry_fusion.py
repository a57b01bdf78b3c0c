"""Wheel odometry and gyro in the tracker's motion filter: predict with them, correct with vision.

The geometric localizer's filter (`motion.py`) predicts a frame at constant velocity. With odometry the
prediction is what the wheels and the gyro measured between the two frames' capture times instead,
and the localizer's own prediction step is left with nothing to do (the state handed to it is already
at the frame's time). Vision fixes then correct it exactly as before (gate, fuse, restart).

- **Time.** `Odometry` messages carry the dead-reckoned pose of their epoch at the end of their window,
  on the robot's monotonic clock (`header.capture_mono_ns`), so the motion between two frames is the
  difference of that pose interpolated at the two capture times; a message lost in between loses
  nothing. Odometry that has not yet reached a frame's time is extrapolated by at most
  `max_extrapolate_s`; later than that, or across an epoch change, the frame falls back to the
  constant-velocity prediction (counted).
- **Noise, slip and bias.** The prediction's covariance grows with the distance and the turn driven
  (`wheel_noise_per_m`, `yaw_noise_per_rad`) plus the gyro bias' spread over the interval; frames with
  the source's slip flag get `slip_inflation` times the noise. Each vision fix that follows another
  within `learn_window_s` measures the gyro bias (yaw turned by odometry minus yaw turned by vision, per
  second) and the wheel scale (distance by vision over distance by odometry); both are learnt by a
  scalar Kalman filter and bounded (`max_gyro_bias_rad_s`, `scale_bounds`). Slip the source does not
  flag is bounded by physics: a wheel speed rising faster than `max_accel_m_s2` (+ `speed_margin_m_s`)
  allows is cut to that, the window's step shortened accordingly (`fusion.slip_limited`). What was cut
  may have been real motion (a robot that did accelerate, or the twin's instant reversals at its
  waypoints), so the motion cut between two frames enters the prediction's covariance along itself.
- **Bad odometry** is rejected with a counted reason before it reaches the buffer: not finite,
  invalid, from another host's clock, from the future or too old, a stalled source clock, a jump (more
  speed or turn rate than a robot has). A saturated gyro or a slip flag down-weights.
- **Validity.** A blind frame (fewer than `min_hits_in_view` hits) may be valid on odometry alone for
  `horizon_s` after the last fix, and only while its position std is below `max_position_std_m`; then
  it is invalid (reason `odometry_horizon`) until vision returns. A frame with lines in view but no fix
  near the prediction is never valid on odometry (`odometry_unconfirmed`) unless those lines lie where the
  prediction has paint (`explained_share` of them: bridged as a blind frame), nor is a frame with fewer hits
  that the prediction itself contradicts (at least `min_hits_to_contradict`, of which less than
  `min_explained` lie on a paint edge with the robot at the predicted pose, no fit): too few lines to fit
  are still lines where the odometry's pose has none. Nor is a frame without a fix whose lines do not speak for
  the prediction and whose colour marks (at least `min_marks_to_contradict`, on a court that has them) lie under
  `marks_explained` on their own colour at the predicted pose: a strip in view where the odometry's pose has
  bare floor, unless a few hits (`lines_over_marks`) lie on paint there. That frame alone is refused (an occluder
  wearing the colour looks the same), no doubt raised. Few lines and few marks, each too little alone but
  together at least `min_evidence_together`, both mostly off at the prediction (hits at most `min_explained` on
  paint, marks under `marks_explained` on their colour) contradict it as enough lines would: a frame against it
  by two independent kinds of evidence.
- **Acquisition.** While the localizer holds hypotheses instead of a track, odometry moves each of them (and
  the lost track's prior) to the frame, as it moves the track: the robot's motion is the same whichever of
  them is the truth.
- **Kidnap.** Vision and odometry disagreeing (a fix that restarts the track far outside the odometry
  prediction's covariance, or `disagree_frames` frames in a row with court lines in view but no fix
  near the prediction) marks every pose invalid (`odometry_disagrees`) and makes the tracker search
  the whole court, from the frame that raised the suspicion (`fused_track`), until `recover_fixes` fixes in
  a row agree again.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import Optional

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from courtloc.common.messages import HOST, Odometry
from courtloc.localizer import acquire, motion
from courtloc.localizer.marks import off_their_colour
from courtloc.localizer.odometry_buffer import OdometryBuffer, OdometryDelta, OdometrySample
from courtloc.world.angles import wrap_angle


class FusionConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    enabled: bool = Field(False, description="predict with odometry from shooter_bridge/odometry")
    horizon_s: float = Field(2.5, gt=0, le=10.0, description="longest a pose stays valid on odometry alone")
    max_position_std_m: float = Field(0.12, gt=0, description="an odometry-only pose less certain than this is invalid")
    buffer_s: float = Field(3.0, gt=0, le=30.0, description="odometry kept for aligning frames")
    resume_hold_s: float = Field(10.0, gt=0, le=60.0, description="after a restart, the odometry saved with the pose "
                                 "is kept this long after its newest sample, so a slow restart still carries the saved "
                                 "pose by odometry (the buffer then holds up to this plus buffer_s)")
    max_extrapolate_s: float = Field(0.08, ge=0, description="odometry may be extrapolated this far to a frame")
    future_tolerance_s: float = Field(0.02, ge=0, description="a sample stamped later than now + this is refused")
    max_speed_m_s: float = Field(6.0, gt=0, description="faster between two samples is a jump, not motion")
    max_yaw_rate_rad_s: float = Field(20.0, gt=0)
    wheel_noise_per_m: float = Field(0.03, ge=0, description="position std per metre driven (slip, wheel wear)")
    wheel_noise_floor_m: float = Field(0.001, ge=0, description="position std added per frame interval")
    yaw_noise_per_rad: float = Field(0.02, ge=0, description="yaw std per radian turned")
    yaw_noise_floor_rad: float = Field(0.0005, ge=0)
    slip_inflation: float = Field(4.0, ge=1.0, description="noise factor while the source flags slip")
    max_accel_m_s2: float = Field(3.0, gt=0, description="the robot cannot speed up faster: wheel speed that "
                                  "does is slip, and the step is shortened to this")
    speed_margin_m_s: float = Field(0.1, ge=0, description="wheel speed noise allowed on top of max_accel")
    gyro_bias_sigma_rad_s: float = Field(0.01, ge=0, description="prior std of the gyro bias")
    max_gyro_bias_rad_s: float = Field(0.05, ge=0, description="the learnt bias is clipped to this")
    scale_sigma: float = Field(0.05, ge=0, description="prior std of the wheel scale (1 = exact)")
    scale_bounds: tuple[float, float] = (0.85, 1.15)
    learn_window_s: tuple[float, float] = Field((0.3, 2.0), description="fix pairs this far apart teach bias/scale")
    min_learn_distance_m: float = Field(0.3, gt=0, description="shorter drives do not teach the wheel scale")
    disagree_chi2: float = Field(25.0, gt=0, description="a vision fix this far (chi-square, 3 dof) from the "
                                 "odometry prediction restarts the track: suspected kidnap")
    disagree_frames: int = Field(3, ge=1, description="frames in a row WITH court lines in view but no fix "
                             "that fits the odometry prediction: suspected kidnap")
    min_hits_in_view: int = Field(40, ge=1, description="a frame with fewer hits is blind, not disagreeing")
    min_hits_to_contradict: int = Field(8, ge=1, description="... but this many can contradict the odometry "
                                        "prediction (min_explained)")
    min_explained: float = Field(0.5, ge=0, le=1, description="a frame of few hits is blind only while this "
                                 "share of them lies on paint at the predicted pose (3 sigma of its covariance)")
    explained_share: float = Field(0.8, gt=0, le=1, description="a frame with lines in view but no fix whose judged "
                                   "hits lie this much on paint at the predicted pose agrees with it: bridged as a "
                                   "blind frame, not a disagreement; a valid fit elsewhere in such a frame is a "
                                   "misread (no doubt)")
    min_marks_to_contradict: int = Field(12, ge=1, description="a frame without a fix showing this many colour marks "
                                         "(court.marks) contradicts the prediction when under marks_explained of them "
                                         "lie on their own colour there")
    marks_explained: float = Field(0.5, ge=0, le=1, description="see min_marks_to_contradict")
    lines_over_marks: int = Field(3, ge=1, description="... unless at least this many hits are judged at the "
                                  "prediction and min_explained of them lie on paint there: lines, however few, are "
                                  "the evidence, and marks may be an occluder's colour")
    min_evidence_together: int = Field(8, ge=1, description="a frame without a fix whose hits (at least "
                                       "lines_over_marks judged) and colour marks, each too few to contradict the "
                                       "prediction alone, are together this many contradicts it when under "
                                       "min_explained of the hits lie on paint there and under marks_explained of "
                                       "the marks on their own colour")
    outline_may_show: bool = Field(True, description="the court's outline may show as an edge (a floor lit "
                                   "brighter than the white mask's threshold): hits on it and on no paint neither "
                                   "explain nor contradict the predicted pose")
    doubt_fixes: int = Field(2, ge=1, description="after a frame the prediction cannot explain (a contradiction, a "
                             "valid fit elsewhere) fixes in a row before poses are valid again; blind frames between "
                             "are not")
    recover_fixes: int = Field(5, ge=1, description="fixes in a row that agree before poses are valid again")


@dataclass
class _Scalar:
    """A scalar random constant learnt from noisy observations (1-D Kalman filter), clipped to bounds."""

    mean: float
    var: float
    lo: float
    hi: float

    def observe(self, value: float, var: float) -> None:
        gain = self.var / (self.var + var)
        self.mean = min(max(self.mean + gain * (value - self.mean), self.lo), self.hi)
        self.var = (1 - gain) * self.var


class OdometryFusion:
    """Per-track odometry state of the infer stage: buffer, learnt bias and scale, counters."""

    def __init__(self, config: FusionConfig) -> None:
        self.config = config
        self.buffer = OdometryBuffer(config.buffer_s)
        self.bias = _Scalar(0.0, config.gyro_bias_sigma_rad_s ** 2, -config.max_gyro_bias_rad_s,
                            config.max_gyro_bias_rad_s)
        self.scale = _Scalar(1.0, config.scale_sigma ** 2, *config.scale_bounds)
        self.rejected: Counter[str] = Counter()
        self.counts: Counter[str] = Counter()
        self.last_fix: Optional[tuple[float, np.ndarray]] = None  # (t, pose) of the last vision fix
        self._last: Optional[OdometrySample] = None  # the last accepted sample as received
        self._corrected: Optional[OdometrySample] = None  # the same with slip limited (what the buffer holds)
        self._speed_ref = 0.0  # the speed the next window may exceed only by what the robot can accelerate
        self._predicted_t: Optional[float] = None  # the frame time the last prediction used odometry for
        self._anchor: Optional[tuple[float, np.ndarray]] = None  # first fix of the pair that teaches bias/scale
        self.suspect = False  # vision disagrees with odometry (kidnap, or a wrong track): invalid until recovered
        self._disagreeing = 0  # frames in a row with lines in view but no fix
        self._agreeing = 0  # fixes in a row since a suspicion
        self.search_pending = False  # the next frame searches the whole court (once per suspicion)
        # A frame the prediction could not explain (contradicted, or a valid fit elsewhere held against) since the
        # last `doubt_fixes` fixes in a row: no pose is valid, blind or fixed, until they agree again.
        self.doubt = False
        self._doubt_fixes = 0

    # ---- input ----------------------------------------------------------------------------------
    def offer(self, message: Odometry, now_s: float) -> bool:
        """Check one message and buffer it; False (counted in `rejected`) when it is not used."""
        reason = self._check(message, now_s)
        if reason:
            self.rejected[reason] += 1
            return False
        if message.gyro_saturated:
            self.counts["gyro_saturated"] += 1
        if message.wheel_slip:
            self.counts["wheel_slip"] += 1
        raw = OdometrySample(t=message.header.capture_mono_ns * 1e-9, epoch=message.epoch,
                             pose=(message.odom_x_m, message.odom_y_m, message.odom_yaw_rad),
                             slip=message.wheel_slip or message.gyro_saturated, source_ns=message.source_time_ns,
                             seq=message.source_seq)
        self.buffer.add(self._limit_slip(raw, message))
        self._last = raw
        return True

    def _limit_slip(self, raw: OdometrySample, message: Odometry) -> OdometrySample:
        """The sample with its step shortened to what the robot can accelerate to (unflagged slip bounded).

        A wheel that slips over-reads its speed from one window to the next faster than the robot can
        accelerate: the step is scaled down to `speed reference + max_accel * window + margin`, and the
        buffer keeps its own corrected dead reckoning (the raw one would carry the slip on)."""
        cfg = self.config
        last, corrected = self._last, self._corrected
        speed = math.hypot(message.vx_m_s, message.vy_m_s)
        if last is None or corrected is None or raw.epoch != last.epoch:
            self._corrected, self._speed_ref = raw, speed
            return raw
        dt = max(raw.t - last.t, message.window_s)
        # The reference follows a falling speed at once and a rising one at most at max_accel; the
        # margin (wheel speed noise) is allowed on top but never accumulates into the reference.
        self._speed_ref = min(speed, self._speed_ref + cfg.max_accel_m_s2 * dt)
        allowed = self._speed_ref + cfg.speed_margin_m_s
        factor = 1.0
        if speed > allowed:
            factor = allowed / speed
            self.counts["slip_limited"] += 1
        step_x, step_y = raw.pose[0] - last.pose[0], raw.pose[1] - last.pose[1]
        pose = (corrected.pose[0] + factor * step_x, corrected.pose[1] + factor * step_y, raw.pose[2])
        cut = (corrected.cut[0] + (1.0 - factor) * step_x, corrected.cut[1] + (1.0 - factor) * step_y)
        self._corrected = OdometrySample(t=raw.t, epoch=raw.epoch, pose=pose, slip=raw.slip or factor < 1.0,
                                         source_ns=raw.source_ns, seq=raw.seq, cut=cut)
        return self._corrected

    def snapshot(self, t: float, max_samples: int = 16) -> tuple[list[OdometrySample], OdometrySample | None]:
        """What a restarted stage needs to carry a pose of time t across the restart (`resume`): the buffered
        samples from the last one at or before t to the newest (at most `max_samples`), and the newest sample
        as received. ([], None) when the buffer does not reach back to t."""
        samples = list(self.buffer.samples)
        first = max((i for i, s in enumerate(samples) if s.t <= t), default=None)
        if first is None or self._last is None or len(samples) - first > max_samples:
            return [], None
        return samples[first:], self._last

    def resume(self, samples: list[OdometrySample], last: OdometrySample) -> bool:
        """Seed a fresh buffer with a snapshot taken before a restart, so odometry arriving after it (the same
        epoch: the MCU kept counting) reaches back to the saved pose. False (nothing changed) when this
        fusion has samples already or the snapshot is not one epoch in time order."""
        ordered = all(a.t < b.t for a, b in pairwise(samples))
        if self.buffer.samples or self._last is not None or not samples or not ordered or \
                any(s.epoch != last.epoch for s in samples):
            return False
        for sample in samples:
            self.buffer.add(sample)
        # A restart can take longer than buffer_s (on a loaded 2-core box 2.4-3.7 s passed from the saved pose to
        # the first frame after the kill): the snapshot must outlive the first frames after it.
        self.buffer.hold_until = last.t + self.config.resume_hold_s
        self._last, self._corrected = last, samples[-1]
        # The speed before the restart is not known: the first step after it (the whole gap) is not slip-limited.
        self._speed_ref = math.inf
        self.counts["resumed"] += 1
        return True

    def _check(self, m: Odometry, now_s: float) -> str:
        cfg = self.config
        values = (m.odom_x_m, m.odom_y_m, m.odom_yaw_rad, m.vx_m_s, m.vy_m_s, m.wz_wheels_rad_s, m.wz_gyro_rad_s)
        if not all(math.isfinite(v) for v in values):
            return "non_finite"
        if not m.header.valid or not m.wheels_valid:
            return "invalid"
        if m.header.capture_host != HOST:
            return "other_host"  # its monotonic clock is not ours: frames cannot be aligned to it
        t = m.header.capture_mono_ns * 1e-9
        if t > now_s + cfg.future_tolerance_s:
            return "future"
        if t < now_s - cfg.buffer_s:
            return "stale"
        last = self._last
        if last is not None and m.epoch == last.epoch:
            if m.source_time_ns <= last.source_ns:
                return "duplicate" if m.source_seq == last.seq else "stalled_clock"
            dt = t - last.t
            if dt <= 0:
                return "stalled_clock"
            moved = math.hypot(m.odom_x_m - last.pose[0], m.odom_y_m - last.pose[1])
            turned = abs(wrap_angle(m.odom_yaw_rad - last.pose[2]))
            if moved > cfg.max_speed_m_s * dt + 0.01 or turned > cfg.max_yaw_rate_rad_s * dt + 0.01:
                # A jump in the cumulative pose: nothing before it can be differenced with anything after.
                self.buffer.clear()
                self._last = self._corrected = None
                return "jump"
        return ""

    # ---- the two hooks around one tracked frame -----------------------------------------------------
    def before_frame(self, state: Optional[motion.MotionState], t: Optional[float]) -> Optional[motion.MotionState]:
        """`state` advanced to the frame time t with odometry (its covariance grown by the odometry's noise),
        or `state` unchanged when odometry cannot say (the filter then predicts at constant velocity)."""
        self._predicted_t = None
        if state is None or t is None or state.t is None:
            return state
        if t <= state.t:
            return state
        delta = self.buffer.delta(state.t, t, self.config.max_extrapolate_s)
        if delta is None:
            newest = self.buffer.samples[-1].t if self.buffer.samples else -math.inf
            self.counts["fallback_late" if newest < t else "fallback_gap"] += 1
            return state
        self.counts["predicted"] += 1
        self._predicted_t = t
        return self._advance(state, delta, t)

    def _advance(self, state: motion.MotionState, delta: OdometryDelta, t: float) -> motion.MotionState:
        cfg = self.config
        dt = t - float(state.t)
        x, y, yaw = state.mean[:3]
        scale = self.scale.mean
        dx, dy = delta.dx * scale, delta.dy * scale
        dyaw = delta.dyaw - self.bias.mean * dt
        c, s = math.cos(yaw), math.sin(yaw)
        mean = state.mean.copy()
        mean[0] = x + c * dx - s * dy
        mean[1] = y + s * dx + c * dy
        mean[2] = wrap_angle(yaw + dyaw)
        mean[3], mean[4], mean[5] = (mean[0] - x) / dt, (mean[1] - y) / dt, dyaw / dt
        # Jacobian of the pose with respect to the previous pose (yaw turns the step) and to the
        # learnt scale and bias, whose uncertainty the step inherits.
        f = np.eye(3)
        f[0, 2] = -(s * dx + c * dy)
        f[1, 2] = c * dx - s * dy
        inflate = cfg.slip_inflation if delta.slip else 1.0
        dist = math.hypot(dx, dy)
        pos_sd = inflate * (cfg.wheel_noise_per_m * dist + cfg.wheel_noise_floor_m)
        yaw_sd = inflate * (cfg.yaw_noise_per_rad * abs(dyaw) + cfg.yaw_noise_floor_rad)
        rot = np.array([[c, -s], [s, c]])
        q = np.zeros((3, 3))
        q[:2, :2] = rot @ np.diag([pos_sd ** 2, pos_sd ** 2]) @ rot.T
        step_world = np.array([mean[0] - x, mean[1] - y])
        q[:2, :2] += np.outer(step_world, step_world) * (self.scale.var / max(scale * scale, 1e-9))
        # What the slip limit cut may have been real motion: the error it may have made, along itself.
        cut_world = rot @ np.array([delta.cut_dx, delta.cut_dy]) * scale
        q[:2, :2] += np.outer(cut_world, cut_world)
        q[2, 2] = yaw_sd ** 2 + self.bias.var * dt * dt
        cov = state.cov.copy()
        cov[:3, :3] = f @ state.cov[:3, :3] @ f.T + q
        cov[:3, 3:] = 0.0  # the velocity slots only carry the odometry's velocity for display
        cov[3:, :3] = 0.0
        # Odometry keeps the track through frames without a fit (blind, or too few lines) for as long as its
        # covariance stays below the motion filter's `max_track_std_m` (then the track is lost and acquisition
        # starts from it): validity is `after_frame`'s, and a view that disagrees ends it (the kidnap rule).
        # Until the seed twin's 4.5 s camera outage this ended at `horizon_s`: the lost track's prior had then
        # grown past deciding, and the run stayed ambiguous after the outage.
        carried = self.last_fix is not None and not self.suspect
        return motion.MotionState(mean=mean, cov=cov, t=t, lost=0 if carried else state.lost)

    def carry_prior(self, prior: acquire.Prior) -> acquire.Prior:
        """A pose prior that moves with the robot: its pose at any time odometry reaches, spread by the same
        noise a track's prediction is (`_advance`), from the prior's own spread. Without it a lost track's
        prior stayed where the track was lost while the robot drove on, its spread grown by
        `motion_sigma_mps`: after 1 s on the robocon2025 twin it was 0.4 m and 30 degrees off and 1 m wide,
        and it decided for a parallel line 1.8 m from the robot. A kidnap prior is not carried (odometry
        missed that move), nor a prior without a pose or a time."""
        if prior.pose is None or prior.t is None or prior.source == "kidnap" or prior.carry is not None:
            return prior
        t0 = prior.t
        yaw_std = prior.yaw_std_rad if prior.yaw_std_rad is not None else math.pi
        cov = np.zeros((6, 6))
        cov[:3, :3] = np.diag([prior.std_m ** 2, prior.std_m ** 2, yaw_std ** 2])
        start = motion.MotionState(mean=np.r_[prior.pose[:3], 0.0, 0.0, 0.0].astype(np.float64), cov=cov, t=t0)

        def at(t: float) -> Optional[tuple[np.ndarray, float, float]]:
            if t == t0:
                return start.pose, prior.std_m, yaw_std
            delta = self.buffer.delta(t0, t, self.config.max_extrapolate_s)
            if delta is None:
                return None
            moved = self._advance(start, delta, t)
            return moved.pose, moved.position_std_m, math.sqrt(float(moved.cov[2, 2]))

        return replace(prior, carry=at)

    def carry_hypotheses(self, state: acquire.Acquiring, t: Optional[float]) -> acquire.Acquiring:
        """The acquisition's hypotheses moved to the frame time t by odometry, each from its own pose (the wheels
        and the gyro measure the robot's motion wherever it is), their covariances grown by its noise; a
        hypothesis odometry cannot reach keeps the constant-velocity prediction. A hypothesis starts from one fit,
        without a velocity: predicted at constant velocity it stays where it was seen, and a view of lines along
        one direction (free along them) cannot pull it after the robot, so its fits there are not valid and do
        not confirm it (replays of the twin's fused runs at 10 fps, robocon2025 `randomised`: 84.6 -> 93.8 %
        valid)."""
        if t is None or not state.hypotheses:
            return state
        moved = []
        for h in state.hypotheses:
            st = h.state
            delta = None if st.t is None or t <= st.t else self.buffer.delta(st.t, t, self.config.max_extrapolate_s)
            if delta is not None:
                st = replace(self._advance(st, delta, t), lost=st.lost)
            moved.append(replace(h, state=st))
        return replace(state, hypotheses=tuple(moved))

    def holds(self, state: Optional[motion.MotionState], t: Optional[float]) -> bool:
        """Whether odometry carried `state` to this frame (t) after a fix, with no kidnap suspected."""
        return isinstance(state, motion.MotionState) and t is not None and self._predicted_t == t \
            and not self.suspect and self.last_fix is not None

    def search_next(self, state: motion.MotionState, cfg: motion.MotionConfig) -> motion.MotionState:
        """The state marked lost, so the tracker searches the whole court next frame (the odometry prior
        is the thing in doubt; the lost state's pose still only picks the symmetry twin)."""
        return motion.MotionState(mean=state.mean, cov=state.cov, t=state.t, lost=max(state.lost, cfg.max_lost_frames))

    def after_frame(self, valid: bool, fused_by_vision: bool, state: Optional[motion.MotionState],
                    t: Optional[float], n_hits: int = 0, contradicted: bool = False,
                    beyond_edge: bool = False, explained: bool = False,
                    marks_against: bool = False) -> tuple[bool, str]:
        """Learn from a vision fix; decide whether a frame without one may be valid on odometry alone
        (`n_hits`: the hits that count as lines in view; `contradicted`: a frame of few hits the prediction
        cannot explain, see `contradicts`; `beyond_edge`: at least `min_hits_to_contradict` hits on the court's
        outline and on no paint at the prediction, which the court model can neither explain nor hold against it,
        `GeometricLocalizer.paint_evidence`; `explained`: lines in view that lie on paint at the prediction, see
        `explains`; `marks_against`: colour marks in view that the prediction leaves off their colour, see
        `marks_contradict`).

        Returns (valid, reason): the frame's validity after fusion and, when odometry decided, why."""
        if t is None or state is None:
            return valid, ""
        if valid and fused_by_vision:
            # A fix near the prediction ends a run of disagreeing frames, also one that cannot vouch yet (in doubt): a
            # run is frames in a row without one (the seed twin's occluded walk at 25 % dropped frames: a contradicted
            # frame, a fix in doubt, one unexplained frame made a kidnap suspicion, and the point-symmetric court kept
            # the search ambiguous for the remaining 20 s).
            self._disagreeing = 0
        if valid and fused_by_vision and self.doubt and not self.suspect:
            self._doubt_fixes += 1
            if self._doubt_fixes < self.config.doubt_fixes:
                self.last_fix = (t, state.pose)
                self.counts["fix_in_doubt"] += 1
                return False, "odometry_unconfirmed"
            self.doubt = False
        if valid and fused_by_vision:
            if self.suspect:
                self._agreeing += 1
                if self._agreeing < self.config.recover_fixes:
                    self.last_fix = (t, state.pose)
                    return False, "odometry_disagrees"
                self.suspect = False
                self.counts["recovered"] += 1
            self._learn(t, state.pose)
            self.last_fix = (t, state.pose)
            return True, ""
        self._anchor = None  # a frame without a fix ends the fix pair (the next fix starts a new one)
        self._doubt_fixes = 0
        if self.suspect:
            self._agreeing = 0
            return False, "odometry_disagrees"
        if valid or self._predicted_t != t:
            return valid, ""
        if n_hits >= self.config.min_hits_in_view and not explained:
            # Court lines in view and still no fix near the odometry prediction: one of them is wrong, and
            # a pose that may be wrong is not valid. (Blind frames are the odometry's to bridge, and so are frames
            # whose lines lie where the prediction has paint: no fit there, but nothing against it either.)
            self.counts["no_fix_in_view"] += 1
            return False, "odometry_unconfirmed"
        if contradicted:
            self.counts["contradicted"] += 1
            self.doubt = True
            return False, "odometry_unconfirmed"
        if beyond_edge:
            # White on the court's outline: a floor lit brighter than the mask's threshold, or by chance lines seen
            # from elsewhere. Not a frame to be valid on, nor evidence of a move (no doubt).
            self.counts["beyond_edge"] += 1
            return False, "odometry_unconfirmed"
        if marks_against:
            self.counts["marks_contradict"] += 1
            return False, "odometry_unconfirmed"
        if self.doubt:
            # Blind after a view the prediction could not explain: the robocon2025 twin's kidnap on its loop (fused):
            # after contradicted frames one fit near the old place was a fix (a view from 1.9 m away that fits
            # there too) and the blind frames after it were valid on odometry 1.7-2.0 m from the robot.
            self.counts["blind_in_doubt"] += 1
            return False, "odometry_unconfirmed"
        if self.last_fix is None or t - self.last_fix[0] > self.config.horizon_s:
            self.counts["beyond_horizon"] += 1
            return False, "odometry_horizon"
        if state.position_std_m > self.config.max_position_std_m:
            self.counts["too_uncertain"] += 1
            return False, "odometry_uncertain"
        self.counts["valid_explained" if explained else "valid_on_odometry"] += 1
        return True, ""

    def explains(self, on_paint: int, judged: int) -> bool:
        """Whether a frame with lines in view (`judged` hits at the prediction, at least `min_hits_in_view`) agrees
        with the prediction though nothing fitted there: `explained_share` of them lie on paint at the predicted
        pose. The seed twin's occluded walk, fused: occluders' edges pulled fits from odometry's pose (1 cm off)
        to valid ones 0.15-0.45 m away, with 80-99 % of the hits on paint at odometry's pose, and after each such
        frame the doubt cost the next fix too."""
        return judged >= self.config.min_hits_in_view and on_paint >= self.config.explained_share * judged

    def few_hits(self, n_hits: int) -> bool:
        """Too few hits to count as lines in view, enough to contradict the prediction."""
        return self.config.min_hits_to_contradict <= n_hits < self.config.min_hits_in_view

    def against_prediction(self, on_paint: int, judged: int, own: int, seen: int) -> tuple[bool, bool]:
        """What a frame without a fix says against the prediction: (contradicted, marks_against), from its hits judged
        there (`judged`, `on_paint` of them on paint; 0, 0 when too few to judge) and its colour marks (`seen` on the
        floor, `own` on their own colour there). Contradicted: few lines off paint (`contradicts`), or few lines and few
        marks both off (`lines_and_marks_contradict`), which raise doubt. Marks against: many marks off their colour
        that the lines do not outweigh (`marks_contradict`, `lines_outweigh_marks`), which refuse the frame alone.

        Why each: a colour strip in view where the prediction has bare floor, and no lines it explains: the robocon2025
        twin's kidnaps (fused sweep, seed 6) put the robot facing the red strip close up, no line in view, and
        odometry's pose 2.8 m away stayed valid for 0.8 s with 1 of 256 marks on red there (all on red at the truth;
        its 3-9 hits on some frames, none on paint there). Only the frame is refused, no doubt is raised: an occluder
        wearing the colour does the same in front of a right prediction, and where its few hits lie on paint there
        (39 of 70 such frames in the robocon2025 `occluded` chain runs, fused) the lines win. Few lines and a few
        marks, each too little to speak alone, both off: the robocon2025 twin's kidnap walk (fused sweep, seed 5): the
        first frame after the teleport showed 10 hits (3 of the 7 judged on paint at odometry's pose) and 4 marks (none
        on their colour there, all at the truth), and odometry's pose 2.3 m off stayed valid for 2-3 frames; as a
        contradiction the blind frame after it is not valid either."""
        contradicted = self.contradicts(on_paint, judged)
        if not contradicted and self.lines_and_marks_contradict(on_paint, judged, own, seen):
            self.counts["contradicted_with_marks"] += 1
            contradicted = True
        return contradicted, self.marks_contradict(own, seen) and not self.lines_outweigh_marks(on_paint, judged)

    def marks_contradict(self, own: int, seen: int) -> bool:
        """Whether a frame's colour marks (`seen` of them on the floor, `own` on their own colour at the predicted
        pose) speak against the prediction: a strip in view where the prediction has bare floor. Lines can be out of
        view (a robot facing a strip close up) while the marks are not."""
        return off_their_colour(own, seen, self.config.min_marks_to_contradict, self.config.marks_explained)

    def lines_outweigh_marks(self, on_paint: int, judged: int) -> bool:
        """Whether a frame's few lines speak for the prediction over its colour marks (`lines_over_marks`)."""
        return judged >= self.config.lines_over_marks and on_paint >= self.config.min_explained * judged

    def lines_and_marks_contradict(self, on_paint: int, judged: int, own: int, seen: int) -> bool:
        """Whether a frame's few lines and few colour marks, each too few to speak alone, speak against the
        prediction together (`min_evidence_together`): both mostly off at it, hits off paint and marks off their colour.
        Many marks off their colour are `marks_contradict`'s, which raises no doubt (an occluder wearing the colour):
        the robocon2025 `occluded` chain runs, fused, have a frame of 3 hits judged (1 on paint) and 54 marks (9 on
        their colour) at a right prediction."""
        c = self.config
        too_few_alone = judged < c.min_hits_to_contradict and seen < c.min_marks_to_contradict
        # At most (not under) min_explained on paint: the marks are all or mostly off too, and the few hits judged are
        # few enough that one more or less judged tips a strict share (the same teleport with the track a few frames
        # older: 3 of 6 on paint instead of 3 of 7, and 3 valid poses 2.3 m off).
        return too_few_alone and judged >= c.lines_over_marks and judged + seen >= c.min_evidence_together \
            and on_paint <= c.min_explained * judged and off_their_colour(own, seen, 1, c.marks_explained)

    def contradicts(self, on_paint: int, judged: int) -> bool:
        """Whether a frame of few hits speaks against the prediction: of the hits judged at the odometry
        prediction (`judged`: all but those on the court's outline and on no paint; too few to count as lines
        in view, enough to say something) less than `min_explained` lie on paint there (`on_paint`). The
        robocon2025 twin, robot teleported into a view of 14-30 hits: those frames were bridged as blind, valid
        on odometry 3.5 m from the robot."""
        return self.few_hits(judged) and on_paint < self.config.min_explained * judged

    def note_acquired(self, state: motion.MotionState, t: Optional[float], n_hits: int) -> None:
        """The localizer decided its pose by acquisition: a vision fix on its own evidence, which ends any
        suspicion odometry had (acquisition never decides a pose the view and its prior do not support)."""
        self.suspect = False
        self.search_pending = False
        self._agreeing = 0
        self.after_frame(True, True, state, t, n_hits)

    def note_vision(self, before: Optional[motion.MotionState], after: Optional[motion.MotionState], n_hits: int,
                    fused: bool, contradicted: bool = False, agrees: bool = False) -> None:
        """Suspect a kidnap when vision and odometry disagree: a fix that restarted the track far from the
        odometry prediction, or `disagree_frames` frames in a row with lines in view and no fix, or with few
        hits that contradict the prediction (`contradicts`). A frame whose lines the prediction explains
        (`agrees`, see `explains`) ends such a run as a fix does."""
        if self.suspect or before is None or self._predicted_t is None or before.t != self._predicted_t:
            return  # while suspected, recovery is counted by after_frame
        if fused and after is not None:
            nu = after.mean[:3] - before.mean[:3]
            nu[2] = wrap_angle(float(nu[2]))
            s = before.cov[:3, :3] + np.diag([0.02 ** 2, 0.02 ** 2, math.radians(1.0) ** 2])
            if float(nu @ np.linalg.solve(s, nu)) > self.config.disagree_chi2:
                self._suspect("restart")
            return
        if (n_hits >= self.config.min_hits_in_view and not agrees) or contradicted:
            self._disagreeing += 1
            if self._disagreeing >= self.config.disagree_frames:
                self._suspect("no_fit_in_view")
        else:
            self._disagreeing = 0

    def _suspect(self, why: str) -> None:
        if not self.suspect:
            self.counts[f"suspect_{why}"] += 1
        self.suspect = True
        self.search_pending = True
        self._agreeing = 0
        self._disagreeing = 0
        self._anchor = None

    def _learn(self, t: float, pose: np.ndarray) -> None:
        """Gyro bias and wheel scale from two vision fixes at least `learn_window_s[0]` apart (an unbroken run
        of fixes) and the odometry between them."""
        lo, hi = self.config.learn_window_s
        if self._anchor is None or t - self._anchor[0] > hi:
            self._anchor = (t, pose)
            return
        t0, pose0 = self._anchor
        dt = t - t0
        if dt < lo:
            return
        self._anchor = (t, pose)
        delta = self.buffer.delta(t0, t, self.config.max_extrapolate_s)
        if delta is None or delta.slip:
            self.counts["learn_skipped"] += 1
            return
        self.counts["learnt"] += 1
        vision_turn = wrap_angle(float(pose[2] - pose0[2]))
        # Two fixes' yaw errors (~0.2 deg each) over dt: the observation's variance.
        yaw_var = 2 * math.radians(0.3) ** 2
        self.bias.observe((delta.dyaw - vision_turn) / dt, yaw_var / (dt * dt))
        odo_dist = math.hypot(delta.dx, delta.dy)
        if odo_dist >= self.config.min_learn_distance_m:
            vision_dist = math.hypot(float(pose[0] - pose0[0]), float(pose[1] - pose0[1]))
            self.scale.observe(vision_dist / odo_dist, 2 * (0.01 / odo_dist) ** 2)

    def health(self) -> dict[str, float | int]:
        detail: dict[str, float | int] = {f"odom_rejected.{k}": v for k, v in self.rejected.items()}
        detail.update({f"fusion.{k}": v for k, v in self.counts.items()})
        detail["fusion.odometry_buffered"] = len(self.buffer.samples)
        detail["fusion.gyro_bias_rad_s"] = round(float(self.bias.mean), 6)
        detail["fusion.wheel_scale"] = round(float(self.scale.mean), 5)
        return detail

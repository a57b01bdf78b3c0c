"""What the next frame starts from: the previous pose, kept while it is still worth tracking from.

A valid pose is kept. A pose that is not valid but still trackable (a degenerate view: only parallel
lines, the position along them unknown) is kept too, so the tracker rides through it. After too many
frames without either, the previous pose is dropped and the model searches the court again, so a robot
that lost track recovers instead of fitting to a stale guess forever.

A model that tracks with a motion filter (the geometric localizer's `track`) keeps its own state in
`motion`: handed back to the model with the next frame, with its own loss rules (`localizer/motion.py`).
Without a track that state is an acquisition (`localizer/acquire.py`) carrying the evidence of where the
robot is: the configured start, a pose the pit set, or the last pose before a restart. `previous` is still
kept, so a swap to a model without a filter tracks on.

`step` is the one predictor-plus-tracker step: the infer stage, its shadow runner and `courtloc eval`
all localise a frame through it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from courtloc.localizer import acquire, motion
from courtloc.localizer.fused_track import fused_track
from courtloc.localizer.odometry_fusion import OdometryFusion
from courtloc.localizer.predictor import Prediction, Predictor


def ages_agree(clock_age_s: float, wall_age_s: float, tolerance_s: float) -> bool:
    """Whether an age measured on a monotonic clock is the wall clock's, within `tolerance_s`: a negative or different
    one means that clock restarted since (a reboot, another host's clock) and its old stamps mean nothing now."""
    return clock_age_s >= 0 and abs(clock_age_s - wall_age_s) <= tolerance_s


@dataclass
class Tracker:
    max_lost_frames: int = 10
    previous: tuple[float, float, float] | None = None
    lost_frames: int = 0
    start: acquire.Prior | None = None  # the configured start: the evidence of a fresh run
    motion: object | None = None
    odometry_reason: str = ""
    clock_agreement_s: float = 0.5  # see state_for
    # A prior stamped on the wall clock (a pose saved before a restart): aged at the first frame that uses it.
    _pending_wall_ns: int | None = field(default=None, repr=False)
    # A prior another thread asked for (the pit's pose): applied by the worker at its next frame.
    _requested: acquire.Prior | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.motion is None and self.start is not None:
            self.motion = acquire.Acquiring(prior=self.start)

    def update(self, x: float, y: float, yaw: float | None, valid: bool, trackable: bool) -> None:
        if yaw is not None and (valid or trackable):
            self.previous = (x, y, yaw)
            self.lost_frames = 0
            return
        self.lost_frames += 1
        if self.lost_frames > self.max_lost_frames:
            self.previous = None

    def step(self, predictor: Predictor, hits: np.ndarray, width: int, height: int, t: float | None,
             fusion: OdometryFusion | None = None, capture_wall_ns: int | None = None,
             marks: np.ndarray | None = None) -> Prediction:
        """Localise one frame from what this tracker knows, and learn from the answer.

        `t` is the frame's capture time in seconds on one clock (the filter predicts over the real interval);
        `capture_wall_ns` its wall-clock time, which ages a pose saved before a restart (None: offline data).
        With `fusion` (a geometric model's serving tracker) odometry predicts between the frames; why
        odometry made a frame invalid is left in `odometry_reason`. `marks`: the frame's colour marks (int16
        rows of (row, col, mark index)), evidence where the court has them.
        """
        state = self.state_for(capture_wall_ns, t)
        prediction, self.motion, self.odometry_reason = fused_track(predictor, fusion, hits, width, height,
                                                                    state, t, marks)
        self.update(prediction.x, prediction.y, prediction.yaw, prediction.valid, prediction.trackable)
        return prediction

    def reset(self) -> None:
        """No track: the next frame acquires, with the configured start as its evidence."""
        self.previous = None
        self.lost_frames = 0
        self.motion = None if self.start is None else acquire.Acquiring(prior=self.start)
        self._pending_wall_ns = None

    def set_prior(self, prior: acquire.Prior, wall_ns: int | None = None) -> None:
        """Drop the track and acquire with this evidence (a pose set by the pit; a pose saved before a
        restart, `wall_ns` its wall-clock time, so the first frame knows how old it is)."""
        self.previous = None
        self.lost_frames = 0
        self.motion = acquire.Acquiring(prior=prior)
        self._pending_wall_ns = wall_ns

    def request_prior(self, prior: acquire.Prior) -> None:
        """From another thread: acquire with this prior from the next frame on (one reference assignment)."""
        self._requested = prior

    def state_for(self, capture_wall_ns: int | None, t: float | None = None) -> object | None:
        """The state to hand the model with a frame captured at `capture_wall_ns` (None: no wall clock), `t` on
        the frames' clock.

        A saved prior that carries its time on the frames' clock keeps it only when that clock agrees with the
        wall clock about its age (within `clock_agreement_s`): then odometry can carry it from that time. Else
        (the clock restarted: a reboot, another camera host) its time is dropped and the wall-clock age spreads it."""
        requested, self._requested = self._requested, None
        if requested is not None:
            self.set_prior(requested)
        if self._pending_wall_ns is not None and capture_wall_ns is not None \
                and isinstance(self.motion, acquire.Acquiring) and self.motion.prior is not None:
            age = max(0.0, (capture_wall_ns - self._pending_wall_ns) * 1e-9)
            prior = self.motion.prior
            if prior.t is not None and (t is None or not ages_agree(t - prior.t, age, self.clock_agreement_s)):
                prior = replace(prior, t=None)
            self.motion = replace(self.motion, prior=replace(prior, age_s=age))
        self._pending_wall_ns = None
        return self.motion

    def handover(self) -> "Tracker":
        """A tracker for another model on the same frames (a shadow candidate): it acquires with this one's
        pose as the evidence, or the configured start without one."""
        # The active model's latest pose, as of the shadow's first frame (a track's own time may be seconds old
        # when the active model is one without a track).
        prior = None
        if self.previous is not None:
            prior = acquire.Prior(source="pit", pose=np.array(self.previous), std_m=0.5, yaw_std_rad=0.35)
        tracker = Tracker(max_lost_frames=self.max_lost_frames, start=self.start)
        if prior is not None:
            tracker.set_prior(prior)
        return tracker

    def tracked_prior(self) -> acquire.Prior | None:
        """The current track as a prior (to save before a restart, or to start a shadow model from)."""
        state = self.motion
        if not isinstance(state, motion.MotionState) or state.lost:
            return None
        return acquire.Prior(source="track", pose=state.pose, std_m=state.position_std_m,
                             yaw_std_rad=math.sqrt(max(float(state.cov[2, 2]), 0.0)), t=state.t)

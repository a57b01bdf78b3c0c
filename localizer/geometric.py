"""The geometric localizer: floor points of a frame's hits -> court pose (x, y, yaw) with a quality.

Per frame (`localize`): with a previous pose, robust fits from it (and turned either side), accepted
when valid and it did not jump; else a few restarts nearby; a frame that still fails is returned
invalid (no global jump). Without a previous pose, a global search (search.py) proposes candidates,
each is refined, the best robust cost wins. The symmetry rule (symmetry.py) then picks between the
answer and its mirror twin.
Over frames (`track`): the motion filter (motion.py) predicts the frame from the past ones, the fit
starts from that prediction, and the answer is the fit fused with the prediction.
Stateless: the caller passes the previous pose (or motion state), so one instance can serve any
number of robots.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple, Union

import numpy as np

from courtloc.localizer import acquire, motion
from courtloc.localizer.config import Half, LocalizerConfig
from courtloc.localizer.court_field import CourtField
from courtloc.localizer.fit import FitResult, fit_pose, fit_poses, quality_score
from courtloc.localizer.hypotheses import merge_converged, placed_by_marks, with_twins, without_misplaced_newcomers
from courtloc.localizer.marks import MarkMap, MarkPoints, off_their_colour, places
from courtloc.localizer.marks_search import MarksSearch
from courtloc.localizer.projection import HitGeometry, ProjectedHits
from courtloc.localizer.result import LocalizeResult
from courtloc.localizer.search import CoarseSearch
from courtloc.localizer.symmetry import by_half, by_previous, mirror
from courtloc.world.camera import CameraModel
from courtloc.world.court import Court

# Restarts around the previous pose when the plain tracking fit fails: (dx m, dy m, dyaw rad).
_TRACK_RESTARTS = [(0.0, 0.0, 0.07), (0.0, 0.0, -0.07), (0.25, 0.0, 0.0), (-0.25, 0.0, 0.0), (0.0, 0.25, 0.0),
                   (0.0, -0.25, 0.0)]


# A probe's basin ties with the tracked fit's only when it explains nearly as many of the hits (`_pinned_or_free`).
_TIE_INLIERS = 0.8

# What a tracker passes from frame to frame: a track, an acquisition (with its prior), or None (no prior).
TrackState = Union[motion.MotionState, acquire.Acquiring, None]


@dataclass(frozen=True)
class TrackStep:
    """One tracked frame: the answer (`result.pose` fused; `result.fit.pose` the frame's own fit; a fused
    frame's `result.fit` stds, validity and quality are the posterior's, see `_fused`) and
    the state to pass with the next frame (a track, or an acquisition: see `GeometricLocalizer.track`)."""

    result: LocalizeResult
    state: TrackState


def _position_cov(fit: FitResult) -> np.ndarray | None:
    cov = fit.covariance
    return None if cov is None or not np.all(np.isfinite(cov)) else np.asarray(cov, np.float64)[:2, :2].copy()


class PaintEvidence(NamedTuple):
    """A frame's hits against one pose (`GeometricLocalizer.paint_evidence`)."""

    on_paint: int  # hits on a paint edge
    judged: int  # all but those of edge_off_paint
    edge_off_paint: int  # hits on the court's outline, on no paint: neither for nor against the pose


class GeometricLocalizer:
    def __init__(self, court: Court, camera: CameraModel, config: LocalizerConfig | None = None,
                 field: CourtField | None = None, batch_starts: bool = True) -> None:
        """`batch_starts=False` fits a frame's starts one at a time (the same results, ~2-3x slower): kept so
        `courtloc bench localize --compare-sequential` can time both paths side by side."""
        self.config = config or LocalizerConfig()
        self.batch_starts = batch_starts
        self.court = court
        self.camera = camera
        # `field` lets variants of one court (e.g. while tuning) share the ~1 s build.
        self.field = field or CourtField.from_court(court, self.config.field_resolution_m)
        self.geometry = HitGeometry(camera)
        self.search = CoarseSearch(self.field, court.area_half_extent_m, self.config.search)
        # On a point-symmetric court every hypothesis has a twin that fits exactly as well: acquisition keeps
        # both alive, whatever its tracking does to either.
        self.symmetric = self.field.point_symmetric()
        self.mark_map = MarkMap(court) if court.marks else None
        self.marks_search = MarksSearch(self.search, self.mark_map, self.symmetric) \
            if self.mark_map is not None else None

    def localize_points(self, floor_points: np.ndarray, previous: np.ndarray | None = None) -> LocalizeResult:
        """Pose from (N, 2) robot-frame floor points (NaN rows ignored). Points carry no pixels, hence no scan
        step: the thin-band bias (band_bias.py) is not applied to them."""
        return self.localize(self.geometry.from_points(floor_points), previous)

    def localize(self, hits: ProjectedHits, previous: np.ndarray | None = None,
                 hint: np.ndarray | None = None) -> LocalizeResult:
        """With `previous`: track (never a global jump); without: global search, and the symmetry twin
        nearer `hint` (a lost track's last pose) unless the mode is 'half' or there is no hint."""
        cfg = self.config
        if previous is not None:
            prev = np.asarray(previous, np.float64)
            return self._finish(self._track(hits, prev), "track", prev)
        best: FitResult | None = None
        candidates = self.search.candidates(hits)
        for res in self._fit_starts(hits, np.array(candidates)) if candidates else []:
            if best is None or (res.valid, -res.cost) > (best.valid, -best.cost):
                best = res
        if best is None:  # no hits at all
            best = fit_pose(self.field, hits, np.zeros(3), cfg.fit, cfg.quality)
        return self._finish(best, "global", None if hint is None else np.asarray(hint, np.float64))

    def paint_evidence(self, hits: ProjectedHits, pose: np.ndarray, pose_cov: np.ndarray,
                       outline: bool = True) -> "PaintEvidence":
        """What a frame's hits say of `pose` as it is (no fit): which lie on a paint edge. A hit is on an edge
        within three standard deviations across it: those of `pose_cov` ((x, y, yaw) covariance) through the hit's
        lever arm, its pixel noise split along / across the view as the fit splits it, and `floor_sigma_m`. The
        fit's `range_sigma` term is left out on purpose: it would excuse far hits by tens of centimetres, and a
        few far hits are what a view from the wrong place often shows.

        With `outline`, the court's outer edge is an edge that may or may not be there: a floor lit brighter than
        the mask's white threshold shows it, where the court model has no paint (the robocon2025 twin under
        randomised light: hits along y = 4 m; judged, they made a right odometry pose look contradicted). Hits
        on it and on no paint are not judged, only counted (`edge_off_paint`).

        Few hits cannot be fitted, but they can still contradict a pose: lines seen where the pose has none."""
        if len(hits) == 0:
            return PaintEvidence(0, 0, 0)
        x, y, yaw = (float(v) for v in pose[:3])
        rot = complex(math.cos(yaw), math.sin(yaw))
        lever = hits.cpoints * rot
        court = lever + complex(x, y)
        cov = np.asarray(pose_cov, np.float64)[:3, :3]
        distance, gx, gy = self.field.lookup(court.real, court.imag)
        norm = np.hypot(gx, gy) + 1e-12
        on_paint = np.abs(distance) <= self._three_sigma(hits, lever, rot, gx / norm, gy / norm, cov)
        if not outline:
            return PaintEvidence(int(np.count_nonzero(on_paint)), len(hits), 0)
        # Distance to the nearer of the outline's side (|y| = hy) and end (|x| = hx) lines, and that line's normal.
        hx, hy = self.court.area_half_extent_m
        qx, qy = np.abs(court.real) - hx, np.abs(court.imag) - hy
        side = qy > qx
        nx = np.where(side, 0.0, np.sign(court.real))
        ny = np.where(side, np.sign(court.imag), 0.0)
        on_outline = np.abs(np.where(side, qy, qx)) <= self._three_sigma(hits, lever, rot, nx, ny, cov)
        unknown = on_outline & ~on_paint
        return PaintEvidence(on_paint=int(np.count_nonzero(on_paint)), judged=int(np.count_nonzero(~unknown)),
                             edge_off_paint=int(np.count_nonzero(unknown)))

    def _three_sigma(self, hits: ProjectedHits, lever: np.ndarray, rot: complex, nx: np.ndarray, ny: np.ndarray,
                     cov: np.ndarray) -> np.ndarray:
        """Three standard deviations of each hit across an edge of unit normal (nx, ny) (`paint_evidence`)."""
        # The edge normal's sensitivity to the pose (x, y, yaw) and the covariance it gives across the edge.
        jac = np.stack([nx, ny, ny * lever.real - nx * lever.imag])
        pose_var = np.einsum("in,ij,jn->n", jac, cov, jac)
        view = hits.cview * rot
        along = nx * view.real + ny * view.imag
        across = ny * view.real - nx * view.imag
        pixel = self.config.fit.pixel_sigma
        var = (np.maximum(pose_var, 0.0) + (along * hits.sigma[:, 0] * pixel) ** 2
               + (across * hits.sigma[:, 1] * pixel) ** 2 + self.config.fit.floor_sigma_m ** 2)
        return 3.0 * np.sqrt(var)

    def track(self, hits: ProjectedHits, state: TrackState, t: float | None = None,
              marks: Callable[[], MarkPoints] | None = None) -> TrackStep:
        """One frame of a track at time t (seconds; None: frames `motion.frame_period_s` apart).

        With a track (`MotionState`): the fit starts from the state's prediction and is fused with it by
        covariance; a frame without a usable fit answers the prediction (invalid). The reset rules are
        motion.py's. Without one (None, or `acquire.Acquiring` carrying a prior): acquisition, whose
        frames are invalid until one hypothesis wins on evidence (acquire.py). A lost track becomes an
        acquisition whose prior is its last pose. `marks`: gives the frame's colour marks on the floor (marks.py),
        called only while acquiring (a tracked frame does not read them),
        evidence for acquisition on a court that has them.
        """
        if state is None:
            state = acquire.Acquiring()
        if isinstance(state, motion.MotionState) and motion.is_lost(state, t, self.config.motion):
            state = acquire.Acquiring(prior=self.lost_prior(state))
        if isinstance(state, acquire.Acquiring):
            return self._acquire(hits, state, t, marks)
        step = self._step(hits, state, t)
        if step.result.status == "jump":
            return self._after_jump(state, step, t)
        if self._view_elsewhere(hits, state, step, t):
            # Coasting through lines that are not where the track has paint wastes the view: the robocon2025 twin's
            # kidnap (vision only, seed 3) teleported the robot into 0.25 s of 40-83 hits, 0-1 on paint at the track,
            # which coasted through them to its lost-frame limit; acquisition then met sparse views and was valid
            # 6.8 s later. Judged as acquisition now, the court is searched in this frame, and a track that was
            # right after all is one of the hypotheses, its last pose the prior that decides for it. The state is
            # stepped again there as a hypothesis (its own rules: no regain guard), on such frames only.
            searching = acquire.Acquiring(prior=self.lost_prior(state),
                                          hypotheses=(acquire.Hypothesis(state, state.pose.copy(), state.t),),
                                          since_search=self.config.acquire.research_frames)
            return self._acquire(hits, searching, t, marks)
        rival = self._rival(hits, step.result.fit) if step.result.valid else None
        if rival is not None and self.config.rival_carried_as_jump and motion.at_frame(state, t):
            # Odometry carried the track here, so it did not slide along a line (the rule's case is the constant-
            # velocity model's): the rival is a valid fit elsewhere, as a jump is, and the fusion judges it against the
            # odometry (`fused_track`: coasting on it, invalid, and held against it when the prediction does not explain
            # the view). The robocon2025 twin's occluded walk, fused through the chain: an occluder's edges made a fit
            # 0.6 m along a line cheaper than the track's (std 2 cm); split, the truth merged into the rival's wider
            # basin 0.1-0.13 m off, and 23 frames were invalid.
            return self._after_jump(state, self._jump(LocalizeResult(pose=rival.pose, fit=rival,
                                                                     mode=step.result.mode), t), t)
        return step if rival is None else self._split(state, step, rival, t)

    def _rival(self, hits: ProjectedHits, fit: FitResult) -> FitResult | None:
        """A fit of this frame elsewhere along the tracked fit's weakest direction that explains the view much
        better, or None. The robocon2025 twin (randomised light): the track slid 1.1 m along y while the view
        showed the centre line and a far arc, each frame's fit valid in the wrong basin (cost 0.39) while the
        true pose 1 m away fitted at 0.02."""
        cfg = self.config
        if fit.cost <= cfg.rival_min_cost:
            return None
        best = None
        for res in self._along_weakest(hits, fit, cfg.rival_probe_m, cfg.rival_min_anisotropy):
            far = math.hypot(*(res.pose[:2] - fit.pose[:2])) > cfg.acquire.merge_m
            if far and (res.valid or res.n_inliers >= fit.n_inliers // 2) and \
                    res.cost <= cfg.rival_cost_ratio * fit.cost and (best is None or res.cost < best.cost):
                best = res
        return best

    def _along_weakest(self, hits: ProjectedHits, fit: FitResult, distances: list[float],
                       min_anisotropy: float = 1.0) -> list[FitResult]:
        """The frame fitted from `fit`'s pose moved each of `distances` either way along its weakest position
        direction, heading kept (`_rival`, `_pinned_or_free`); none without distances, without a finite covariance,
        or when the weakest direction's std is less than `min_anisotropy` times the strongest's."""
        if not distances or fit.covariance is None:
            return []
        cov = np.asarray(fit.covariance, np.float64)[:2, :2]
        if not np.all(np.isfinite(cov)):
            return []
        variances, axes = np.linalg.eigh(cov)
        if variances[-1] < min_anisotropy ** 2 * max(variances[0], 0.0):
            return []
        weakest = axes[:, -1]
        offsets = [(sign * d * weakest[0], sign * d * weakest[1], 0.0) for d in distances for sign in (1, -1)]
        return self._fit_starts(hits, fit.pose + np.array(offsets))

    def _regain_rival(self, hits: ProjectedHits, fit: FitResult) -> FitResult | None:
        """A fit of this frame from `fit`'s pose turned by `regain_yaw_probes_rad` either way that converged to
        another pose and explains the view as well (within acquisition's tie, with at least half the inliers),
        or None. Run only on a drifted track's re-anchoring frames (a few per minute), so its cost is small."""
        cfg, acfg = self.config, self.config.acquire
        if not cfg.regain_yaw_probes_rad:
            return None
        starts = [fit.pose + (0.0, 0.0, sign * d) for d in cfg.regain_yaw_probes_rad for sign in (1, -1)]
        limit = acquire.tie_limit(fit.cost, acfg)
        enough = max(fit.n_inliers // 2, cfg.quality.min_inliers)
        for res in self._fit_starts(hits, np.array(starts)):
            if not acquire.same_pose(res.pose, fit.pose, acfg) and res.cost <= limit and \
                    (res.valid or res.n_inliers >= enough):
                return res
        return None

    def _split(self, state: motion.MotionState, step: TrackStep, rival: FitResult, t: float | None) -> TrackStep:
        """The track and a rival fit become acquisition hypotheses (as after a jump): the frame is invalid, the
        frames to come decide, the track's last pose the prior."""
        assert isinstance(step.state, motion.MotionState)
        answer = self._status(self._answer(step.result, step.result.pose, invalid=True), "ambiguous")
        rival_state = motion.start(rival.pose, rival.covariance, t, self.config.motion)
        return self._undecided(state, answer, (step.state, rival_state), t)

    def _view_elsewhere(self, hits: ProjectedHits, state: motion.MotionState, step: TrackStep,
                        t: float | None) -> bool:
        """Whether a frame the track fitted nothing in shows lines the constant-velocity prediction has no paint
        for (`MotionConfig.unexplained_min_hits`, `unexplained_share`); judged with the prediction's covariance, so
        a track long coasted is contradicted only by lines well away from its paint."""
        mcfg = self.config.motion
        coasted = isinstance(step.state, motion.MotionState) and step.state.lost > state.lost
        if not coasted or mcfg.unexplained_min_hits == 0 or len(hits) < mcfg.unexplained_min_hits \
                or motion.at_frame(state, t):
            return False
        evidence = self.paint_evidence(hits, step.state.pose, step.state.cov[:3, :3])
        return (evidence.judged >= mcfg.unexplained_min_hits
                and evidence.on_paint < mcfg.unexplained_share * evidence.judged)

    def _after_jump(self, state: motion.MotionState, step: TrackStep, t: float | None) -> TrackStep:
        """A valid fit the track cannot explain: the robot was moved, or the fit snapped to a parallel line
        0.5-1.6 m away, heading right (the robocon2025 twin bench: restarted at such a fit and confirmed by
        the next frame, which fitted the same wrong line, 24 valid poses up to 1.6 m off). One frame cannot
        tell which: the track's continuation and the fit both become acquisition hypotheses, the track's
        last pose the prior (step 8), and the frames to come decide (the one that stops fitting dies)."""
        mcfg = self.config.motion
        kept = motion.coast(motion.predict(state, t, mcfg), mcfg)
        return self._undecided(state, step.result, (kept, step.state), t)

    def _undecided(self, track: motion.MotionState, answer: LocalizeResult,
                   candidates: tuple[motion.MotionState, ...], t: float | None) -> TrackStep:
        """`answer` for this frame, and an acquisition between `candidates`, first seen now, with the track's
        last pose as the prior."""
        hypotheses = tuple(acquire.Hypothesis(s, s.pose.copy(), t) for s in candidates)
        return TrackStep(answer, acquire.Acquiring(prior=self.lost_prior(track), hypotheses=hypotheses))

    def lost_prior(self, state: motion.MotionState) -> acquire.Prior:
        """A lost track's last pose as the prior of the acquisition after it."""
        return acquire.Prior(source="track", pose=state.pose,
                             std_m=max(state.position_std_m, self.config.acquire.lost_std_m),
                             yaw_std_rad=max(math.sqrt(max(float(state.cov[2, 2]), 0.0)),
                                             math.radians(self.config.acquire.lost_yaw_std_deg)), t=state.t)

    def _step(self, hits: ProjectedHits, state: motion.MotionState, t: float | None,
              guard_regain: bool = True) -> TrackStep:
        """One frame of a track. `guard_regain`: a drifted track's re-anchoring fit must have no rival
        (`_regain_rival`), and must be followed by a valid frame; acquisition, which steps its hypotheses here,
        has its own rules for deciding."""
        mcfg = self.config.motion
        constant_velocity = not motion.at_frame(state, t)
        pred = motion.predict(state, t, mcfg)
        res = self.localize(hits, pred.pose)
        pinned_fit = res.fit if res.fit.valid else None
        if constant_velocity:
            # Only there: odometry's prediction follows the robot along the lines on its own, and a demoted fit only
            # widened its posterior (robocon2025 twin, occluded, fused through the chain: 97.3 -> 91.0 % valid).
            res = self._pinned_or_free(hits, res, pred.pose)
        # A valid fit gave way to a clearly better one beside it (`_better_probe`): where the track cannot follow,
        # that one is a jump as the valid fit would have been (the seed twin's clean walk: a track drifted 0.33 m
        # is re-found that way).
        rebased = pinned_fit is not None and res.fit.cost < pinned_fit.cost
        r = motion.measurement_cov(res.fit.covariance, mcfg)
        if (res.valid or res.trackable) and r is not None:
            innov = motion.innovation(pred, res.pose, r)
            if innov.chi2 <= mcfg.gate_chi2:
                new = motion.update(pred, res.pose, r, innov)
                fused = self._fused(res, new)
                weak = 0 if res.fit.valid else pred.weak + 1
                drifted = pred.position_std_m > mcfg.regain_std_m or (
                    mcfg.regain_weak_frames > 0 and pred.weak >= mcfg.regain_weak_frames)
                if fused.valid and drifted and not res.fit.valid:
                    # A view that pins only some directions (parallel lines) does not re-anchor a drifted track: along
                    # the others the posterior is the prediction, which is what drifted (robocon2025 twin, randomised,
                    # vision only: 20 frames of such views, the velocity 0.6 m/s off and the posterior std 7 cm with
                    # the track 0.45 m off; the next frames answered valid 0.52 m off). A fit valid on its own does.
                    fused = self._answer(fused, new.pose, invalid=True)
                elif fused.valid and drifted:
                    # The track may have drifted (coasting, degenerate views): a lone valid fit then decides too
                    # much (one fit 0.55 m off with a 0.08 m std at the seed court's end line was fused as
                    # valid). It re-anchors the track; the next agreeing frame answers valid.
                    fused = self._status(self._answer(fused, new.pose, invalid=True), "confirming")
                    if guard_regain and mcfg.regain_weak_frames > 0:
                        # Re-anchored, not yet regained: one more frame without a valid fit makes it drifted again
                        # (a re-anchoring fit 0.3 m off, three trackable-only frames, then a valid fit 0.78 m off).
                        weak = mcfg.regain_weak_frames - 1
                    if guard_regain and self._regain_rival(hits, res.fit) is not None:
                        # ... unless the view fits as well elsewhere: then the track stays drifted, and only a
                        # re-anchoring view with no such rival brings validity back (robocon2025 twin, vision only:
                        # after 10 frames of trackable-only fits the first valid one was 1.26 m and 17 degrees off
                        # with a 3 cm std, a start turned 0.35 rad fitted at the same cost 0.6 m away, and the next
                        # frame, of 13 hits, agreed with the wrong one: a valid pose 0.87 m off).
                        fused = self._status(fused, "ambiguous")
                        weak = max(pred.weak + 1, mcfg.regain_weak_frames)
                return TrackStep(fused, replace(new, weak=weak))
            if res.valid or rebased:
                # The evidence disagrees with the track: restart the track there, but one frame is not
                # enough to answer valid from (a single bad fit at a line end jumped 0.4-0.6 m on the
                # seed recording): the next frame must agree with the restarted track.
                return self._jump(res, t)
        if guard_regain and res.fit.beyond_jump and constant_velocity:
            # A valid fit farther from the constant-velocity prediction than a track may move is a jump too, not
            # a frame to coast through: the seed twin's fast walk (2.5 m/s) seen at 10 fps reversed at the area's
            # edge, the prediction overshot by 0.5 m, two frames' fits at the truth (100 inliers, 1-2 cm std) were
            # set aside, and the coasting track settled in a basin 1.5 m off whose fits were valid (then 4.4 m
            # off, valid again after a re-anchoring: tests/data/seed_fast_10fps_drift.json). Not where odometry
            # carried the state to this frame (its time is the frame's): odometry saw the reversal, and such a
            # fit is a misread view (the seed twin's occluded walk, fused, lost its track for 20 s that way); nor
            # for an acquisition's hypotheses (guard_regain False), whose evidence belongs to where they are.
            return self._jump(res, t)
        return TrackStep(self._answer(res, pred.pose, invalid=True), motion.coast(pred, mcfg))

    def _pinned_or_free(self, hits: ProjectedHits, res: LocalizeResult, predicted: np.ndarray) -> LocalizeResult:
        """`res` when its fit, valid on its own, pins the pose; else the fit as trackable only, its covariance widened
        towards the other place that explains the view as well (`tie_probe_m`). A fit's covariance is the curvature of
        its own basin: in a view of lines along one way it can be that of a few hits near a line's end while a basin
        0.5 m along the lines fits every hit as well (robocon2025 twin, fast walk seen at 15 fps: such fits, 2 cm std,
        held the track at one place while the robot drove on at 2.4 m/s; fused as valid measurements they stopped its
        velocity in three frames and answered 15 valid poses up to 1.9 m off). Free along that way, the fit leaves it
        to the prediction (and to `regain_weak_frames`).

        A probe that settles within `track_max_jump_m` of the prediction and explains the view clearly better (its
        cost's tie limit below the fit's cost, with as many inliers) is the frame's fit instead, then judged the same
        way: `_track` keeps the lowest-cost start, and the probes are starts too (`_better_probe`)."""
        cfg, fit = self.config, res.fit
        if not fit.valid:
            return res
        probes = self._along_weakest(hits, fit, cfg.tie_probe_m)  # none without a finite covariance
        better = self._better_probe(fit, probes, predicted)
        if better is not None:
            res = self._finish(better, res.mode, predicted)
            fit = res.fit
            if not fit.valid:
                return res
            probes = self._along_weakest(hits, fit, cfg.tie_probe_m)
        limit = acquire.tie_limit(fit.cost, cfg.acquire)
        for other in probes:
            offset = np.array([other.pose[0] - fit.pose[0], other.pose[1] - fit.pose[1], 0.0])
            apart = math.hypot(offset[0], offset[1])
            if apart > cfg.acquire.merge_m and other.cost <= limit and other.n_inliers >= _TIE_INLIERS * fit.n_inliers:
                cov = np.asarray(fit.covariance, np.float64) + np.outer(offset, offset)
                free = replace(fit, valid=False, quality=min(fit.quality, 0.49), covariance=cov,
                               position_std_m=max(fit.position_std_m, apart))
                return LocalizeResult(pose=res.pose, fit=free, mode=res.mode, alternatives=res.alternatives,
                                      status=res.status)
        return res

    def _better_probe(self, fit: FitResult, probes: list[FitResult], predicted: np.ndarray) -> FitResult | None:
        """The lowest-cost probe that explains the frame clearly better than `fit` (even its tie limit is below the
        fit's cost), with at least as many inliers, within `track_max_jump_m` of the prediction; else None.
        A tracked fit can settle in a worse basin beside the right one: the robocon2025 twin's minus-x walk (vision
        only, seed 7) fitted 0.26 m off at 10 times the cost of a probe's fit at the truth, the probe was set
        aside as the same place (closer than `acquire.merge_m`), and four more such frames drifted the track to a
        valid pose 0.57 m off."""
        cfg = self.config
        best: FitResult | None = None
        for other in probes:
            if (acquire.tie_limit(other.cost, cfg.acquire) < fit.cost and other.n_inliers >= fit.n_inliers
                    and math.hypot(*(other.pose[:2] - predicted[:2])) <= cfg.track_max_jump_m
                    and (best is None or other.cost < best.cost)):
                best = other
        return best

    def _jump(self, res: LocalizeResult, t: float | None) -> TrackStep:
        """A valid fit the track cannot follow: invalid this frame, the track restarted there (`track` turns it
        into an acquisition between the track's continuation and the fit, `_after_jump`)."""
        return TrackStep(self._status(self._answer(res, res.pose, invalid=True), "jump"),
                         motion.start(res.pose, res.fit.covariance, t, self.config.motion))

    # ---- acquisition (acquire.py has the rule) ------------------------------------------------------
    def _acquire(self, hits: ProjectedHits, state: acquire.Acquiring, t: float | None,
                 marks: Callable[[], MarkPoints] | None = None) -> TrackStep:
        cfg, acfg = self.config, self.config.acquire
        prior = None if state.prior is None else state.prior.at(t)
        # Odometry carried the hypotheses to this frame (fusion), rather than the constant-velocity model.
        carried = bool(state.hypotheses) and all(motion.at_frame(h.state, t) for h in state.hypotheses)
        live: list[tuple[LocalizeResult, acquire.Hypothesis]] = []
        for h in state.hypotheses:
            step = self._step(hits, h.state, t, guard_regain=False)
            if step.state is not None and step.state.lost > h.state.lost and self._carried_through(hits, h.state, t):
                # Odometry carried it here and the frame fits nothing but says nothing against it either: the
                # frame is no loss (acquire.py, rule 1).
                step = TrackStep(self._status(step.result, "carried"), replace(step.state, lost=h.state.lost))
            if step.state is not None and step.state.lost < acfg.drop_lost_frames:
                # Pinned once a fit of it is valid: from then on the view has pinned where it is, and where
                # that happened is evidence too (acquire.Hypothesis.pinned_sighting).
                sighting = h.pinned_sighting
                if not h.pinned and step.result.valid:
                    sighting = acquire.Sighting(step.state.pose.copy(), t, step.state.cov[:2, :2].copy())
                live.append((step.result, replace(h, state=step.state, pinned=h.pinned or step.result.valid,
                                                  pinned_sighting=sighting, frames=h.frames + 1)))
        since = state.since_search + 1
        points = marks() if self.mark_map is not None and marks is not None else None
        searched: FitResult | None = None
        unpinned_cost: float | None = None
        # Search again when there is nothing to track, every research_frames frames, and on every frame
        # that would confirm a decision: a view an unpinnable pose explains better must not confirm one.
        searched_now = not live or since >= acfg.research_frames or state.agreed > 0
        if searched_now:
            # A start or a pit pose that odometry carries vouches for where the robot is, and the wheels tie a
            # hypothesis's frames together: a view that nearly pins it seeds hypotheses then. Without odometry the
            # filter's posterior of such views hovers at a valid fit's limit, and a confirmation that a valid fit
            # would have made in 0.2 s restarted for 1.7 s (the robocon2025 twin's minus_x_start, vision only).
            declared = prior is not None and prior.pose is not None and prior.source in ("start", "pit") \
                and prior.carry is not None
            found, searched, unpinned_cost = self._search_hypotheses(hits, t, near_pinned=declared, marks=points)
            live += found
            since = 0
        live = merge_converged(with_twins(live) if self.symmetric else live, acfg, carried)
        behind = acquire.frames_behind([h for _, h in live], [res.fit.cost for res, _ in live], acfg)
        live = [(res, replace(h, behind=b)) for (res, h), b in zip(live, behind) if b < acfg.tie_drop_frames]
        seen = [] if points is None or not len(points) else [self.mark_map.evidence(h.pose, points) for _, h in live]
        if seen:
            live, seen = without_misplaced_newcomers(live, seen, len(points), acfg)
        kept = acquire.within_cap([h for _, h in live], acfg)
        overflow = any(h.behind == 0 for i, (_, h) in enumerate(live) if i not in kept)
        live = [live[i] for i in kept]
        if seen:
            seen = [seen[i] for i in kept]
            live = [(res, replace(h, marks=tuple(a + b for a, b in zip(h.marks, ev))))
                    for (res, h), ev in zip(live, seen)]
            if not any(places(own, len(points), acfg.marks_min) for own, _ in seen):
                # Colour marks in view that no hypothesis puts on their own colour: the robot is none of them
                # (or the marks are an occluder's), so the court is searched again next frame, not research_frames
                # later (the robocon2025 twin's first kidnap, replayed: the truth, showing 66 marks, was found
                # only by the search 15 frames after the first, 0.5 s of usable views later).
                since = max(since, acfg.research_frames)
            live = placed_by_marks(live, points, seen, acfg, self.mark_map, self.court.area_half_extent_m)
        hypotheses = tuple(h for _, h in live)
        if not live:
            fit = searched or fit_pose(self.field, hits, np.zeros(3), cfg.fit, cfg.quality)
            # Nothing fits: the answer (invalid) is the prior's pose when there is one, not a fit anywhere.
            pose = prior.pose if prior is not None and prior.pose is not None else fit.pose
            res = self._answer(LocalizeResult(pose=fit.pose, fit=fit, mode="global"), pose, invalid=True)
            return TrackStep(self._status(res, "searching"), acquire.Acquiring(prior, (), 0, since))
        half = cfg.half if cfg.symmetry == "half" else None
        court_marks = self.mark_map is not None
        # While a decision is being confirmed the prior is judged at the time it was made: its spread growing
        # frame by frame must not undo a decision the next frames only have to confirm.
        t_eval = state.decided_t if state.agreed > 0 and state.decided_t is not None else t
        decision = acquire.decide(list(hypotheses), prior, half, t_eval, acfg, cfg.centre_margin_m, court_marks)
        unexplained = 0 if decision.explained else state.unexplained + 1
        if unexplained >= acfg.kidnap_frames and prior is not None and prior.source in ("track", "kidnap"):
            unexplained = 0
            # The view contradicts the lost track's last pose: the robot was moved (acquire.py, rule 2).
            prior = (acquire.Prior("kidnap", pose=prior.pose, std_m=max(prior.std_m, acfg.kidnap_sigma_m), t=prior.t)
                     if prior.source == "track" and acfg.kidnap_sigma_m > 0 else None)
            decision = acquire.decide(list(hypotheses), prior, half, t_eval, acfg, cfg.centre_margin_m, court_marks)
            if not decision.explained:
                prior = None
                decision = acquire.decide(list(hypotheses), None, half, t_eval, acfg, cfg.centre_margin_m, court_marks)
        if overflow:
            # A candidate this view fits was cut: none of those kept is the only explanation of it.
            decision = replace(decision, index=None)
        poses = [h.pose for h in hypotheses]
        held = self._held_decision(state, list(hypotheses), prior, half, t_eval) \
            if decision.index is None and not overflow else None
        if held is not None:
            # Only hypotheses first seen this frame stand in the way of the decision being confirmed: they have no
            # evidence yet, so the frame neither confirms nor undoes it; the next frame judges them with a frame
            # of evidence (still tying, they block it then). The robocon2025 twin's kidnaps, vision only: a marks
            # decision, its hypothesis tracked 35 frames with 988 marks for it, was restarted seven times in 1.3 s
            # by near-ties a confirming frame's search proposed and the next frame dropped.
            res = self._pending(live[held][0], poses, held, "ambiguous")
            return TrackStep(res, acquire.Acquiring(prior, hypotheses, state.agreed, since, decided_pose=poses[held],
                                                    decided_t=state.decided_t, unexplained=unexplained))
        if decision.index is None:
            best = self._nearest(list(hypotheses), prior, t)
            res = self._pending(live[best][0], poses, best, "ambiguous")
            return TrackStep(res, acquire.Acquiring(prior, hypotheses, 0, since, unexplained=unexplained))
        res, chosen = live[decision.index]
        same = state.decided_pose is not None and _same_decision(state.decided_pose, chosen.pose)
        # A view an unpinnable pose explains better than the decided one confirms nothing. Compared with the
        # decided fit itself, not only the search's: the search can miss the tracked basin (robocon2025, a
        # view of the three-point line's straight part into its arc: its best fits cost 0.2 against the
        # tracked 0.02, and one invalid among them blocked a marks decision for 35 frames).
        blocked = unpinned_cost is not None and unpinned_cost < res.fit.cost
        agreed = (state.agreed + 1 if same else 1) if res.valid and not blocked else 0
        if same and not blocked and res.status == "carried":
            # A frame that only carried the decided hypothesis neither confirms nor undoes the decision: the
            # robocon2025 twin's kidnap (fused, seed 3) decided by the marks after 0.5 s of views, then faced bare
            # floor for 5 s; every such frame restarted the confirmation, and the hypotheses died of them.
            agreed = state.agreed
        if agreed and points is not None and off_their_colour(self.mark_map.evidence(chosen.pose, points)[0],
                                                              len(points), acfg.marks_min, acfg.marks_decided_share):
            # Colour marks in view that the decided pose does not put on their own colour: painted where it says
            # there is none, or the robot is elsewhere (an occluder's colour only delays the decision). Evidence
            # against the decision: it starts again. The robocon2025 twin's drive_kidnap through the chain (fused,
            # kept and replayed): a lost track's prior decided for a basin 2.3 m off while 150-260 marks of the
            # strip the robot faced fell on bare floor there; confirmed by three frames, 9 valid poses 2.1-2.2 m off.
            agreed = 0
        if agreed > 1 and not decision.marks and searched_now and (
                searched is None or searched.cost > acquire.tie_limit(res.fit.cost, acfg)):
            # A prior decides relative to the hypotheses found; a search that found nothing as good as the
            # decided fit cannot have found its rivals either: the frame confirms nothing (nor undoes). On the
            # robocon2025 twin (a kidnap run's frames replayed vision only, tests/data/r25_blind_search_prior.json)
            # a lost track's prior decided for a basin 1.8 m off that one search had found; the true pose, as
            # valid a fit, never was, and the confirming frames' searches ended far above both: 13 valid poses
            # 1.8 m off. Colour marks judge the hypothesis itself, once it has moved: the robocon2025 drive
            # facing the red strip (tests/test_localizer_marks.py) is blind to the search for its whole 1.3 s.
            agreed = state.agreed
        # A marks decision on hypotheses odometry carries needs a frame less: the wheels tie its frames together (the
        # robocon2025 twin's kidnaps, fused: four confirming frames, then 4 s of bare floor before the fifth; the same
        # frame less without odometry confirmed a wrong start 5 m off in an occluded walk).
        marks_frames = acfg.confirm_frames_marks_carried if carried else acfg.confirm_frames_marks
        needed = (marks_frames if decision.marks else
                  acfg.confirm_frames_kidnap if decision.kidnap else
                  acfg.confirm_frames_tight if decision.tight else acfg.confirm_frames)
        if agreed >= needed and chosen.state.lost == 0 and res.valid:
            return TrackStep(LocalizeResult(pose=res.pose, fit=res.fit, mode="acquired"), chosen.state)
        res = self._pending(res, poses, decision.index, "confirming")
        return TrackStep(res, acquire.Acquiring(prior, hypotheses, agreed, since, decided_pose=chosen.pose,
                                                decided_t=t_eval if agreed > 1 else t, unexplained=unexplained))

    def _pending(self, res: LocalizeResult, poses: list[np.ndarray], index: int, status: str) -> LocalizeResult:
        """An acquiring frame's answer (invalid, with `status`): hypothesis `index`'s pose, the others alternatives."""
        answer = self._answer(res, poses[index], invalid=True)
        return LocalizeResult(pose=answer.pose, fit=answer.fit, mode=answer.mode, status=status,
                              alternatives=[p for i, p in enumerate(poses) if i != index])

    def _held_decision(self, state: acquire.Acquiring, hypotheses: list[acquire.Hypothesis],
                       prior: acquire.Prior | None, half: Half | None, t: float | None) -> int | None:
        """The index of the hypothesis being confirmed when the evidence would still decide for it without the
        hypotheses first seen this frame (None: no decision was being confirmed, or it is undone)."""
        if state.agreed == 0 or state.decided_pose is None:
            return None
        seasoned = [i for i, h in enumerate(hypotheses) if h.frames > 0]
        if len(seasoned) == len(hypotheses):
            return None
        cfg = self.config
        decision = acquire.decide([hypotheses[i] for i in seasoned], prior, half, t, cfg.acquire, cfg.centre_margin_m,
                                  self.mark_map is not None)
        if decision.index is None:
            return None
        index = seasoned[decision.index]
        return index if _same_decision(state.decided_pose, hypotheses[index].pose) else None

    def _carried_through(self, hits: ProjectedHits, state: motion.MotionState, t: float | None) -> bool:
        """Whether a hypothesis odometry carried to this frame (its time is the frame's) outlives a frame with no
        usable fit of it: still known to `carry_max_std_m`, and the view does not speak against it (at least
        `carry_min_explained` of the hits judged at its pose lie on paint: `paint_evidence`)."""
        acfg = self.config.acquire
        if not motion.at_frame(state, t) or state.position_std_m > acfg.carry_max_std_m:
            return False
        evidence = self.paint_evidence(hits, state.mean[:3], state.cov[:3, :3])
        return evidence.on_paint >= acfg.carry_min_explained * evidence.judged

    def _search_hypotheses(self, hits: ProjectedHits, t: float | None, near_pinned: bool = False,
                           marks: MarkPoints | None = None
                           ) -> tuple[list[tuple[LocalizeResult, acquire.Hypothesis]], FitResult | None, float | None]:
        """Every valid global-search fit within the tie of the best, and each one's mirror twin; the
        lowest-cost fit of all (what a frame without hypotheses answers, invalid); and the cost of an invalid fit
        that explains the view better than every valid one found (None: a valid one is the best). `near_pinned`
        (a declared pose odometry carries): when no fit is valid, those pinned to `search_near_pinned_std_m` seed
        unpinned hypotheses instead of none. `marks` (the frame's colour marks) add the coarse poses that put them on
        their colour to the line search's candidates (marks_search.py)."""
        acfg = self.config.acquire
        cost = self.search.costs(hits)
        candidates = self.search.pick(cost)
        if self.marks_search is not None and marks is not None and len(marks):
            candidates += self.marks_search.candidates(cost, marks, candidates, self.config.search)
        if not candidates:
            return [], None, None
        firsts = self._fit_starts(hits, np.array(candidates))
        lowest = min(firsts, key=lambda f: f.cost)
        q = self.config.quality
        # Valid fits, and the ones the view cannot pin down (e.g. only parallel lines: free along them) but
        # that fit well: the latter are never decided, they keep a near-miss elsewhere from being decided.
        ok = sorted((f for f in firsts if f.valid or (f.n_inliers >= q.min_inliers and f.inlier_ratio >= 0.5)),
                    key=lambda f: f.cost)
        if not ok:
            return [], lowest, None
        any_valid = any(f.valid for f in ok)
        limit = acquire.tie_limit(ok[0].cost, acfg)
        ok = [f for f in ok if f.cost <= limit][:acfg.max_hypotheses]
        # No fit valid on its own, but one within the tie pins the position nearly as well: its hypotheses start
        # unpinned, and the frames that follow pin them (the robocon2025 twin's kidnap start, fused: 24 frames of
        # views whose fit at the truth had a 0.08-0.12 m std searched and found nothing, 0.8 s).
        near = acfg.search_near_pinned_std_m if near_pinned else 0.0
        unpinned_cost = _unpinned_cost(ok, any_valid, near)
        if not any_valid:
            # Only those: fits free along the lines in view would fill the hypotheses' cap, each one fitting every
            # later frame of such a view, and nothing would be searched or decided again (the held-out seed
            # recording: 2,090 frames ambiguous after its track was lost).
            ok = [f for f in ok if f.position_std_m <= near]
            if not ok:
                return [], lowest, None
        twins = self._fit_starts(hits, np.array([mirror(f.pose) for f in ok]))
        fits = sorted([f for f in ok + twins if f.cost <= limit and (f.valid or f.inlier_ratio >= 0.5)],
                      key=lambda f: f.cost)
        mcfg = self.config.motion
        found = [(LocalizeResult(pose=f.pose, fit=f, mode="global"),
                  acquire.Hypothesis(motion.start(f.pose, f.covariance, t, mcfg), f.pose.copy(), t, _position_cov(f),
                                     f.valid)) for f in fits]
        return found, lowest, unpinned_cost

    def _nearest(self, hypotheses: list[acquire.Hypothesis], prior: acquire.Prior | None, t: float | None) -> int:
        """The hypothesis an undecided frame answers (invalid): nearest a pose prior, else the best fit."""
        if prior is None or prior.pose is None:
            return 0
        return min(range(len(hypotheses)), key=lambda i: acquire.hypothesis_distance2(
            prior, hypotheses[i], self.config.acquire))

    @staticmethod
    def _status(res: LocalizeResult, status: str) -> LocalizeResult:
        return LocalizeResult(pose=res.pose, fit=res.fit, mode=res.mode, alternatives=res.alternatives,
                              status=status)

    def _fused(self, res: LocalizeResult, state: motion.MotionState) -> LocalizeResult:
        """A usable fit fused into the filter: the answer is the posterior pose, and so are its stds.

        Valid when the fit is, or when it is trackable and the posterior is as well constrained as the
        quality limits ask of a fit (position std, yaw std): the answer's uncertainty is the posterior's,
        not the frame's alone. E.g. a degenerate view (lines along one direction) fused with a tight
        prediction, or a fit whose range-error term puts its yaw std just over the limit. An answer from
        the prediction alone (`_answer(..., invalid=True)`) stays invalid.
        """
        q = self.config.quality
        pos_std, yaw_std = state.position_std_m, math.sqrt(max(float(state.cov[2, 2]), 0.0))
        valid = res.fit.valid or (res.trackable and pos_std <= q.max_position_std_m
                                  and yaw_std <= math.radians(q.max_yaw_std_deg))
        fit = replace(res.fit, valid=bool(valid), position_std_m=pos_std, yaw_std_rad=yaw_std,
                      quality=quality_score(res.fit.n_inliers, res.fit.inlier_ratio, pos_std, yaw_std, valid, q))
        return self._answer(LocalizeResult(pose=res.pose, fit=fit, mode=res.mode), state.pose)

    def _answer(self, res: LocalizeResult, pose: np.ndarray, invalid: bool = False) -> LocalizeResult:
        """`res` answering `pose` instead of its fit's pose (the fit stays, for its diagnostics)."""
        fit = res.fit
        if invalid:
            fit = replace(fit, valid=False, quality=min(fit.quality, 0.49))
        alternatives = [mirror(pose)] if self.config.symmetry == "both" else []
        return LocalizeResult(pose=pose, fit=fit, mode=res.mode, alternatives=alternatives)

    def _track(self, hits: ProjectedHits, prev: np.ndarray) -> FitResult:
        """Fit from the previous pose; if that fails, a few nearby starts (the robot cannot teleport).

        A frame that still fails comes back invalid rather than replaced by a global search: a lone
        ambiguous frame must not throw the track across the court. The caller keeps its last valid pose
        and drops it when stale (then the next call searches globally).
        """
        cfg = self.config
        # The basin of the right alignment can be narrower than a frame's turn: also start turned by
        # +-track_yaw_starts_rad and keep the lowest robust cost (all starts run in one batched fit).
        # Cost, not validity, decides: validity is a threshold on the stds, and a valid start with twice
        # the cost of an invalid one is the worse fit of the same hits (a rendered twin frame: 30 cm off).
        dyaw = cfg.track_yaw_starts_rad
        starts = [prev] + ([prev + (0.0, 0.0, dyaw), prev + (0.0, 0.0, -dyaw)] if dyaw > 0 else [])
        fits = self._fit_starts(hits, np.array(starts))
        first = fits[0]
        for other in fits[1:]:
            if other.cost < first.cost:
                first = other

        def within_jump(fit: FitResult) -> bool:
            return fit.valid and math.hypot(*(fit.pose[:2] - prev[:2])) <= cfg.track_max_jump_m

        if within_jump(first):
            return first
        best = first
        for res in self._fit_starts(hits, prev + np.array(_TRACK_RESTARTS)):
            if (within_jump(res), -res.cost) > (within_jump(best), -best.cost):
                best = res
        if best.valid and not within_jump(best):
            best = replace(best, valid=False, quality=min(best.quality, 0.49), beyond_jump=True)
        return best

    def _fit_starts(self, hits: ProjectedHits, starts: np.ndarray) -> list[FitResult]:
        cfg = self.config
        if self.batch_starts:
            return fit_poses(self.field, hits, starts, cfg.fit, cfg.quality)
        return [fit_pose(self.field, hits, s, cfg.fit, cfg.quality) for s in starts]

    def _finish(self, fit: FitResult, mode: str, previous: np.ndarray | None) -> LocalizeResult:
        cfg = self.config
        if cfg.symmetry == "half" or previous is None:
            pose = by_half(fit.pose, cfg.half, cfg.centre_margin_m)
        else:
            pose = by_previous(fit.pose, previous)
        fit = replace(fit, pose=pose)
        alternatives = [mirror(pose)] if cfg.symmetry == "both" else []
        return LocalizeResult(pose=pose, fit=fit, mode=mode, alternatives=alternatives)


def _unpinned_cost(fits: list[FitResult], any_valid: bool, near_pinned_std_m: float) -> float | None:
    """The cost of the best of `fits` (the search's within the tie, by cost) when it is invalid and explains the view
    better than every valid one; None when a valid one is the best. When the search found no valid fit (`any_valid`
    False: seeded by nearly pinned ones), an unpinnable fit's cost only when it is below every nearly pinned one's."""
    if fits[0].valid:
        return None
    if any_valid:
        return fits[0].cost
    loose = [f.cost for f in fits if f.position_std_m > near_pinned_std_m]
    near = [f.cost for f in fits if f.position_std_m <= near_pinned_std_m]
    return loose[0] if loose and (not near or loose[0] < near[0]) else None


def _same_decision(decided: np.ndarray, pose: np.ndarray) -> bool:
    """The same hypothesis as the one decided last frame: within what a robot moves in a frame or two."""
    return math.hypot(decided[0] - pose[0], decided[1] - pose[1]) <= 0.5

"""Settings of the geometric localizer (validated at load; a bad value fails with the field's name)."""
from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

SymmetryMode = Literal["half", "previous", "both"]
Half = Literal["+x", "-x"]


class FitConfig(BaseModel):
    """Robust Gauss-Newton fit of (x, y, yaw) to the court's distance field."""

    model_config = ConfigDict(extra="forbid")
    pixel_sigma: float = Field(1.0, gt=0, description="hit position noise in pixels")
    floor_sigma_m: float = Field(0.005, gt=0, description="court-model error floor in metres")
    tilt_sigma_deg: float = Field(0.1, ge=0, description="prior std of the body's per-frame pitch and roll "
                                  "(0: assume a rigid, level camera)")
    range_sigma: float = Field(0.0, ge=0, description="model error per metre of range")
    tukey_c: float = Field(4.0, gt=0, description="Tukey biweight cut-off in sigmas")
    huber_c: float = Field(2.0, gt=0, description="Huber threshold in sigmas for the first iterations")
    huber_iterations: int = Field(2, ge=0, description="Huber iterations before switching to Tukey")
    max_iterations: int = Field(6, ge=1)
    max_residual_m: float = Field(0.5, gt=0, description="hits farther than this from paint are ignored")
    gate_cos: float = Field(-0.2, ge=-1, le=1,
                            description="min cos between the scan ray and the edge normal (far edges only)")
    step_tol_m: float = Field(5e-4, gt=0, description="stop when a step moves less than this")
    # The thin-band sampling bias (band_bias.py), calibrated per camera and renderer; both empty: off.
    band_bias_widths: list[float] = Field(default_factory=list, max_length=16,
                                          description="band widths along the scan ray, in scan steps (increasing)")
    band_bias_samples: list[float] = Field(default_factory=list, max_length=16,
                                           description="expected hit offset past the far edge at those widths, in "
                                           "scan steps, beyond what edge_offset_px already removes")

    @model_validator(mode="after")
    def _band_bias_knots(self) -> "FitConfig":
        w, v = self.band_bias_widths, self.band_bias_samples
        if len(w) != len(v) or len(w) == 1:
            raise ValueError(f"band_bias_widths and band_bias_samples: need equal lengths, 0 or >= 2 (got {len(w)} "
                             f"and {len(v)})")
        if any(b <= a for a, b in zip(w, w[1:])) or any(not math.isfinite(x) for x in w + v):
            raise ValueError(f"band_bias_widths must be finite and increasing, band_bias_samples finite: {w}, {v}")
        return self


class QualityConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    inlier_sigmas: float = Field(3.0, gt=0, description="|residual| below this many sigmas is an inlier")
    min_inliers: int = Field(12, ge=3)
    min_inlier_ratio: float = Field(0.35, ge=0, le=1)
    max_position_std_m: float = Field(0.08, gt=0, description="worst-direction position std (degeneracy)")
    max_yaw_std_deg: float = Field(1.0, gt=0)


class SearchConfig(BaseModel):
    """Global (cold-start) search on a coarse, clipped distance field."""

    model_config = ConfigDict(extra="forbid")
    coarse_factor: int = Field(10, ge=1, description="coarse cell = factor x fine cell")
    clip_m: float = Field(0.4, gt=0)
    yaw_step_deg: float = Field(3.0, gt=0, le=30)
    max_points: int = Field(60, ge=4, description="hits used by the coarse search (nearest ranges first)")
    max_range_m: float = Field(9.0, gt=0)
    candidates: int = Field(8, ge=1, description="coarse minima refined")
    area_margin_m: float = Field(0.0, description="search |x|,|y| up to the court's robot area + this")
    marks_candidates: int = Field(4, ge=0, description="on a court with colour marks, coarse minima of the line cost "
                                  "plus marks_weight x the share of the frame's marks off their colour, refined too "
                                  "(marks_search.py; 0: none)")
    marks_weight: float = Field(0.3, ge=0, description="m of line cost a frame's marks all off their colour count as")
    marks_min: int = Field(12, ge=1, description="fewer colour marks in range than this add no candidates")
    marks_max_points: int = Field(30, ge=4, description="colour marks spread over the ones in range that the marks "
                                  "search sums at every coarse pose")


class MotionConfig(BaseModel):
    """Constant-velocity Kalman filter of the tracker (motion.py). crosseval tunes `measurement_scale`
    and `accel_sigma_mps2` by tracking the tuning recording; these defaults are what its first stage
    (the fit settings) tracks with, the package carries the tuned values."""

    model_config = ConfigDict(extra="forbid")
    accel_sigma_mps2: float = Field(1.0, gt=0,
                                    description="white-noise acceleration (spectral density sqrt), x and y")
    yaw_accel_sigma_dps2: float = Field(60.0, gt=0, description="the same for yaw, degrees")
    measurement_scale: float = Field(2.0, gt=0, description="the fit's covariance std is multiplied by this")
    floor_position_m: float = Field(0.005, ge=0, description="added to the fit's position std (per axis)")
    floor_yaw_deg: float = Field(0.05, ge=0, description="added to the fit's yaw std")
    initial_speed_mps: float = Field(1.0, gt=0, description="velocity std of a new track")
    initial_yaw_rate_dps: float = Field(60.0, gt=0, description="yaw-rate std of a new track")
    gate_chi2: float = Field(25.0, gt=0,
                             description="innovation chi-square (3 dof) above which a fit is not fused")
    velocity_tau_s: float = Field(1.0, ge=0, description="predicted velocity decays with this time constant "
                                  "(0: constant velocity)")
    max_lost_frames: int = Field(10, ge=0, description="frames without a usable fit before the court is searched "
                                 "again (the last pose still picks the symmetry twin)")
    max_gap_s: float = Field(1.0, gt=0, description="a longer gap between frames also searches the court again")
    max_track_std_m: float = Field(0.5, gt=0, description="a track known worse than this (worst-direction position "
                                   "std, e.g. after riding degenerate views) is dropped: a valid fit near it would be "
                                   "a new acquisition, not evidence for the track")
    frame_period_s: float = Field(0.085, gt=0, description="assumed time between frames that carry no time")
    regain_std_m: float = Field(0.16, gt=0, description="a track whose prediction is known worse than this (worst-"
                                "direction position std) answers its next valid fit invalid ('confirming'): "
                                "validity comes back from two agreeing frames, not one")
    regain_weak_frames: int = Field(5, ge=0, description="... and so does a track the constant-velocity model "
                                    "carried through this many frames in a row without a fit valid on its own (0: "
                                    "never): its std can stay under regain_std_m while it drifts along a degenerate "
                                    "view. Such a track answers a view that pins only some directions invalid, and "
                                    "only a fit valid on its own re-anchors it (a view that fits the same wrong place "
                                    "two frames running still answers valid)")
    unexplained_min_hits: int = Field(30, ge=0, description="a frame the track fits nothing in, with at least this "
                                      "many hits judged at the constant-velocity prediction (0: never) ...")
    unexplained_share: float = Field(0.2, ge=0, le=1, description="... of which less than this share lie on paint "
                                     "there, is taken as an acquisition frame at once, the track one of its hypotheses "
                                     "and its last pose the prior: the robot was moved, or the prediction ran off "
                                     "(with odometry carrying the track, fusion judges such frames)")


class AcquireConfig(BaseModel):
    """Acquisition without a track (acquire.py): hypotheses, the evidence that decides between them, and
    the frames a decision must hold before the first valid pose."""

    model_config = ConfigDict(extra="forbid")
    tie_ratio: float = Field(1.5, ge=1, description="a valid fit within this factor of the best cost is a hypothesis")
    tie_abs: float = Field(0.02, ge=0, description="... plus this much cost (a near-perfect best fit)")
    max_hypotheses: int = Field(8, ge=1)
    merge_m: float = Field(0.3, gt=0, description="hypotheses closer than this (and merge_rad) are one")
    merge_rad: float = Field(0.15, gt=0)
    drop_lost_frames: int = Field(3, ge=1, description="a hypothesis without a usable fit this many frames dies")
    carry_max_std_m: float = Field(0.25, gt=0, description="a hypothesis odometry carries to the frame loses nothing "
                                   "by a frame without a usable fit of it (toward drop_lost_frames, or a decision's "
                                   "confirmation) while its position std is at most this and the view does not speak "
                                   "against it (carry_min_explained)")
    carry_min_explained: float = Field(0.5, ge=0, le=1, description="... at least this share of the hits judged at "
                                       "its pose lie on paint (fusion's min_explained)")
    tie_drop_frames: int = Field(3, ge=1, description="a hypothesis whose fit costs more than the tie of the best "
                                 "(tie_ratio, tie_abs) this many frames in a row dies; until then it decides nothing")
    confirm_frames: int = Field(3, ge=1, description="frames a decided hypothesis must answer valid before the "
                                "track starts")
    confirm_frames_tight: int = Field(3, ge=1, description="... when a pose prior within tight_prior_m decided")
    confirm_frames_kidnap: int = Field(10, ge=1, description="... when a kidnap prior decided (it admits wrong "
                                       "hypotheses metres away: the view must change before one is trusted)")
    confirm_frames_marks: int = Field(5, ge=1, description="... when colour marks alone decided (the hypothesis "
                                      "has already moved marks_motion_m or turned marks_turn_deg since first seen)")
    confirm_frames_marks_carried: int = Field(4, ge=1, description="... and when odometry carried the hypotheses to "
                                              "the frame (the wheels vouch for the motion between its frames)")
    tight_prior_m: float = Field(1.0, gt=0, description="a pose prior this well known (std, grown by its age) is "
                                 "tight")
    research_frames: int = Field(15, ge=1, description="while undecided, search the court again this often (and "
                                 "on the next frame when colour marks in view lie on no hypothesis's own colour)")
    motion_sigma_mps: float = Field(0.5, gt=0, description="a pose prior's position std grows this much per second")
    yaw_sigma_rps: float = Field(0.75, gt=0, description="... and its heading std, radians per second")
    prior_gate_chi2: float = Field(16.0, gt=0, description="a hypothesis farther from a pose prior (d^2) is not "
                                   "explained by it")
    lost_std_m: float = Field(0.5, gt=0, description="a lost track's pose is a prior at least this wide (a track "
                              "dropped after degenerate views can sit on a parallel line 1.85 m away, its std unaware)")
    lost_yaw_std_deg: float = Field(10.0, gt=0, description="... and its heading a prior at least this wide (a "
                                    "gyro-fused track knows its yaw to a fraction of a degree, so a vision fix a few "
                                    "degrees off was never explained by it and the track never came back)")
    decide_chi2: float = Field(9.0, gt=0, description="the hypothesis a pose prior decides for must lie within this "
                               "d^2 of it (3 sigma): farther, the truth may be a pose the search could not pin down")
    kidnap_frames: int = Field(8, ge=1, description="frames a lost track's pose must explain no hypothesis before "
                               "it is taken for a kidnap (the truth may just not be found yet in a degenerate view); "
                               "a kidnap it is not dropped for may meanwhile show a view it explains elsewhere")
    kidnap_sigma_m: float = Field(0.0, ge=0, description="a lost track's pose that explains no hypothesis (the robot "
                                  "was moved) is kept as a prior this wide, heading unknown (0: dropped)")
    max_decide_std_m: float = Field(1.5, gt=0, description="a pose prior grown wider than this (its std plus "
                                    "motion_sigma_mps per second of age) decides nothing: within its 3 sigma lie wrong "
                                    "basins metres away, and the true pose may be one the search has not found yet")
    max_decide_yaw_std_deg: float = Field(30.0, gt=0, description="deciding, a prior's heading std counts at most "
                                          "this wide (it grows by yaw_sigma_rps per second): it may decide for a "
                                          "hypothesis heading where it said, never for one turned 90 degrees")
    decide_log_ratio: float = Field(4.6, gt=0, description="the prior decides when the best hypothesis is this much "
                                    "more likely (log) than every other (4.6: 100 to 1)")
    marks_min: int = Field(12, ge=1, description="colour marks (court.marks) a hypothesis must have seen agree "
                           "(disagree) before they speak for (against) it")
    marks_ratio: float = Field(4.0, ge=1, description="... and outnumber the others by this factor (a red robot or "
                               "ball seen beside the blue strip must not overrule the strip)")
    marks_motion_m: float = Field(0.5, gt=0, description="marks decide without a prior only for a hypothesis tracked "
                                  "this far (or turned marks_turn_deg) since first seen: a near-tie of the same side "
                                  "sees the same strip, and a standing robot's misread view stays misread")
    marks_turn_deg: float = Field(20.0, gt=0)
    marks_strong: int = Field(100, ge=1, description="... half as far (and half the turn) for one with at least this "
                              "many marks for it: a kidnapped robot that saw the marks for 0.3 s and then bare floor "
                              "waited seconds, and the misread view the motion rule guards against showed 12")
    search_near_pinned_std_m: float = Field(0.15, ge=0, description="with a start or pit pose odometry carries, a "
                                            "search whose fits are none valid still seeds hypotheses (unpinned) from "
                                            "those that pin the position to this std (0: never); tracked, a few such "
                                            "frames pin them")
    marks_decided_share: float = Field(0.5, ge=0, le=1, description="a frame showing marks_min marks or more of "
                                       "which the decided hypothesis puts fewer than this share on their own colour "
                                       "undoes the decision's count (0: never)")


class LocalizerConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    field_resolution_m: float = Field(0.01, gt=0, le=0.05)
    edge_offset_px: float = Field(0.2, description="hits sit this far beyond the paint edge along the image ray")
    max_range_m: float = Field(12.0, gt=0)
    symmetry: SymmetryMode = "previous"
    half: Half = Field("+x", description="the robot's half in 'half' mode (the other modes take the start from the "
                       "caller: acquire.Prior)")
    centre_margin_m: float = Field(0.3, ge=0,
                                   description="within this of x=0 the half rule picks by heading instead")
    track_yaw_starts_rad: float = Field(0.15, ge=0, description="tracking also starts this far either side in yaw "
                                        "(0: one start)")
    track_max_jump_m: float = Field(0.5, gt=0, description="a tracked pose moving more than this is re-checked")
    rival_probe_m: list[float] = Field(
        default_factory=lambda: [0.6],
        description="a valid tracked frame is also fitted from its pose moved this far either way along its weakest "
        "direction ([]: never): a track that slid along a weakly pinned line keeps fitting the wrong place validly")
    rival_cost_ratio: float = Field(0.5, gt=0, le=1, description="a probe fitting at most this fraction of the "
                                    "tracked fit's cost elsewhere makes the track and the probe rival hypotheses")
    rival_min_cost: float = Field(0.15, ge=0, description="... when the tracked fit costs more than this (below it the "
                                  "fit is as good as the view allows and a ratio of two tiny costs is noise)")
    rival_min_anisotropy: float = Field(3.0, ge=1, description="... and its position std along its weakest direction "
                                        "is at least this many times the strongest's (a view pinned both ways has no "
                                        "line to slide along; the probes cost as much as the frame's own fit)")
    rival_carried_as_jump: bool = Field(True, description="a rival of a track odometry carried to the frame is a jump "
                                        "there (the caller's fusion judges it against the odometry), not a split into "
                                        "two hypotheses")
    tie_probe_m: list[float] = Field(
        default_factory=lambda: [0.6], max_length=8,
        description="a tracked fit valid on its own is also fitted from its pose moved this far either way along its "
        "weakest direction ([]: never); a start that converges elsewhere (beyond acquire.merge_m) and explains the "
        "view as well (within acquire's tie, with 80 % of the inliers) shows the view does not pin that direction, "
        "whatever the fit's covariance says: the fit counts as trackable only, free towards the other place. Only "
        "where the constant-velocity model predicts (not a state odometry carried to the frame)")
    regain_yaw_probes_rad: list[float] = Field(
        default_factory=lambda: [0.2, 0.35], max_length=8,
        description="a drifted track's re-anchoring fit (motion.regain_std_m, regain_weak_frames) is also fitted from "
        "its pose turned this far either way ([]: never); a start that converges elsewhere (beyond acquire.merge_m / "
        "merge_rad) and explains the view within acquire's tie (tie_ratio, tie_abs) makes the frame 'ambiguous' and "
        "keeps the track drifted: the view does not pin the pose, whatever the fit's covariance says")
    fit: FitConfig = FitConfig()
    motion: MotionConfig = MotionConfig()
    quality: QualityConfig = QualityConfig()
    search: SearchConfig = SearchConfig()
    acquire: AcquireConfig = AcquireConfig()

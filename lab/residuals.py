"""Where a package's residual model is off: hit residuals at the true poses of labelled frames, by the kind
of paint a hit lies on and its range (`courtloc localizer residuals`).

A residual is the signed distance of a hit from the modelled far edge of the paint it belongs to, in the
fit's own terms (edge offset, far-edge flip, thin-band bias when configured), positive past the edge.
At the true pose a correct model leaves medians near zero in every bin; a bin that is not says which part
of the model to look at (this is how the thin-band bias was found: docs/localizer.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from courtloc.lab.seed_frames import SeedFrames
from courtloc.localizer.config import FitConfig, LocalizerConfig
from courtloc.localizer.court_field import CourtField, is_thin_band
from courtloc.localizer.fit import FrameTerms, frame_residuals
from courtloc.localizer.projection import FloorProjector, ProjectedHits
from courtloc.world.camera import CameraModel

RANGE_EDGES_M = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
MIN_HITS = 30


@dataclass
class AtPose:
    """Per hit of one frame at a given pose, as the fit sees it there."""

    d: np.ndarray  # residual (m), hit past the modelled far edge positive
    usable: np.ndarray  # bool: counted by the fit (gates, max residual)
    half_width: np.ndarray  # court_field.band_half_width of the band the hit belongs to
    step_normal_m: np.ndarray  # one scan step's floor length along the edge normal (0: unknown)


def residuals_at(field: CourtField, hits: ProjectedHits, pose: np.ndarray, cfg: FitConfig) -> AtPose:
    """The fit's residual model evaluated at `pose` (tilt zero), with what the band bias needs per hit."""
    params = np.zeros((1, 5))
    params[0, :3] = pose[:3]
    d, j, usable = frame_residuals(field, FrameTerms(hits, cfg), params, cfg, tilt=False)
    gx, gy = j[0, 0], j[0, 1]  # the edge normal, scaled by 1/sigma
    rot = np.exp(1j * pose[2])
    ray = hits.cray * rot
    ray_cos = (gx * ray.real + gy * ray.imag) / (np.hypot(gx, gy) + 1e-300)
    court = hits.cpoints * rot + complex(pose[0], pose[1])
    return AtPose(d=d[0], usable=usable[0], half_width=field.nearest(court.real, court.imag, field.half_width),
                  step_normal_m=hits.step_m * np.abs(ray_cos))


def residual_table(camera: CameraModel, field: CourtField, cfg: LocalizerConfig, frames: SeedFrames,
                   indices: np.ndarray) -> list[dict]:
    """One row per (paint kind, range bin) with at least MIN_HITS usable hits: n, median and mean
    residual (cm). Kinds: 'thin band' (a line under 2 x THIN_BAND_HALF_WIDTH_M wide), 'other' (wide paint
    such as a floor's far edge, or no band within reach: unmodelled white things)."""
    projector = FloorProjector(camera, cfg.edge_offset_px, cfg.max_range_m)
    kinds, ranges, values = [], [], []
    for i in indices:
        h = frames.hits[i]
        hits = projector.project(h[:, 0], h[:, 1])
        if len(hits) == 0:
            continue
        at = residuals_at(field, hits, frames.truth[i], cfg.fit)
        kinds.append(is_thin_band(at.half_width)[at.usable])
        ranges.append(hits.range_m[at.usable])
        values.append(at.d[at.usable])
    thin, rng, res = (np.concatenate(a) if a else np.zeros(0) for a in (kinds, ranges, values))
    thin = thin.astype(bool)
    rows = []
    for kind, sel_kind in (("thin band", thin), ("other", ~thin)):
        for lo, hi in zip(RANGE_EDGES_M, RANGE_EDGES_M[1:]):
            sel = sel_kind & (rng >= lo) & (rng < hi)
            if np.count_nonzero(sel) >= MIN_HITS:
                rows.append({"kind": kind, "range_m": [lo, hi], "n": int(np.count_nonzero(sel)),
                             "median_cm": float(np.median(res[sel]) * 100), "mean_cm": float(np.mean(res[sel]) * 100)})
    return rows

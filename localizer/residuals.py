"""Where a package's residual model is off: hit residuals at the true poses of labelled frames, by the kind
of paint a hit lies on and its range (`courtloc localizer residuals`).

A residual is the signed distance of a hit from the modelled far edge of the paint it belongs to, in the
fit's own terms (edge offset, far-edge flip, thin-band bias when configured), positive past the edge.
At the true pose a correct model leaves medians near zero in every bin; a bin that is not says which part
of the model to look at (this is how the thin-band bias was found: docs/localizer.md).
"""
from __future__ import annotations

import numpy as np

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.court_field import THIN_BAND_HALF_WIDTH_M, CourtField
from courtloc.localizer.projection import FloorProjector
from courtloc.localizer.seed_eval import SeedFrames
from courtloc.sim.camera import CameraModel

RANGE_EDGES_M = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0)
MIN_HITS = 30


def residual_table(camera: CameraModel, field: CourtField, cfg: LocalizerConfig, frames: SeedFrames,
                   indices: np.ndarray) -> list[dict]:
    """One row per (paint kind, range bin) with at least MIN_HITS usable hits: n, median and mean
    residual (cm). Kinds: 'thin band' (a line under 2 x THIN_BAND_HALF_WIDTH_M wide), 'other' (wide paint
    such as a floor's far edge, or no band within reach: unmodelled white things)."""
    from courtloc.localizer.fit import _FrameTerms, _residuals

    projector = FloorProjector(camera, cfg.edge_offset_px, cfg.max_range_m)
    kinds, ranges, values = [], [], []
    for i in indices:
        h = frames.hits[i]
        hits = projector.project(h[:, 0], h[:, 1])
        if len(hits) == 0:
            continue
        params = np.zeros((1, 5))
        params[0, :3] = frames.truth[i]
        d, _, usable = _residuals(field, _FrameTerms(hits, cfg.fit), params, cfg.fit, tilt=False)
        court = hits.cpoints * np.exp(1j * frames.truth[i, 2]) + complex(*frames.truth[i, :2])
        hw = field.nearest(court.real, court.imag, field.half_width)
        keep = usable[0]
        kinds.append(((hw > 0) & (hw < THIN_BAND_HALF_WIDTH_M))[keep])
        ranges.append(hits.range_m[keep])
        values.append(d[0, keep])
    thin, rng, res = (np.concatenate(a) if a else np.zeros(0) for a in (kinds, ranges, values))
    rows = []
    for kind, sel_kind in (("thin band", thin.astype(bool)), ("other", ~thin.astype(bool))):
        for lo, hi in zip(RANGE_EDGES_M, RANGE_EDGES_M[1:]):
            sel = sel_kind & (rng >= lo) & (rng < hi)
            if np.count_nonzero(sel) >= MIN_HITS:
                rows.append({"kind": kind, "range_m": [lo, hi], "n": int(np.count_nonzero(sel)),
                             "median_cm": float(np.median(res[sel]) * 100), "mean_cm": float(np.mean(res[sel]) * 100)})
    return rows

"""Calibrating the thin-band bias (`courtloc.localizer.band_bias`) from labelled frames: the median
residual per band-width bin at the true poses."""
from __future__ import annotations

from typing import Iterable

import numpy as np

from courtloc.lab.residuals import residuals_at
from courtloc.localizer.config import FitConfig
from courtloc.localizer.court_field import CourtField, is_thin_band
from courtloc.localizer.projection import ProjectedHits

# Bins of band width in steps for the calibration; their centres become the knots. Past 4 steps a band
# behaves as a wide one (edge_offset_px covers it).
BIN_EDGES = (0.25, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
MIN_HITS_PER_BIN = 50


def band_samples(field: CourtField, hits: ProjectedHits, pose: np.ndarray,
                 cfg: FitConfig) -> tuple[np.ndarray, np.ndarray]:
    """(band width in steps, residual in steps) of the usable thin-band hits of one frame at `pose`, with
    the band bias off: what `calibrate` bins."""
    plain = cfg.model_copy(update={"band_bias_widths": [], "band_bias_samples": []})
    at = residuals_at(field, hits, pose, plain)
    keep = at.usable & is_thin_band(at.half_width) & (at.step_normal_m > 0)
    step_n = at.step_normal_m[keep]
    return 2.0 * at.half_width[keep] / step_n, at.d[keep] / step_n


def calibrate(field: CourtField, frames: Iterable[tuple[ProjectedHits, np.ndarray]],
              cfg: FitConfig) -> tuple[list[float], list[float]]:
    """Knots (band widths, expected offsets, both in steps) from labelled frames ((hits, true pose) pairs):
    the median residual of each BIN_EDGES bin with at least MIN_HITS_PER_BIN hits, at the bin's centre.
    Fewer than two such bins: ([], []) (no bias modelled)."""
    widths, offsets = [], []
    for hits, pose in frames:
        w, off = band_samples(field, hits, np.asarray(pose, np.float64), cfg)
        widths.append(w)
        offsets.append(off)
    w = np.concatenate(widths) if widths else np.zeros(0)
    off = np.concatenate(offsets) if offsets else np.zeros(0)
    knots_w, knots_v = [], []
    for lo, hi in zip(BIN_EDGES, BIN_EDGES[1:]):
        sel = (w >= lo) & (w < hi)
        if np.count_nonzero(sel) >= MIN_HITS_PER_BIN:
            knots_w.append(round(0.5 * (lo + hi), 4))
            knots_v.append(round(float(np.median(off[sel])), 4))
    return (knots_w, knots_v) if len(knots_w) >= 2 else ([], [])

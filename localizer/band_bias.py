"""The thin-band sampling bias: where the scan's hits past a narrow line really lie.

The radial scan samples each ray once per pixel and reports the first non-white sample after a white
one. Past a wide band's far edge that sample is a fraction of a step beyond the edge on average, which
the floor table's `edge_offset_px` removes. A band narrower than about two steps along the ray is seen
only when a sample lands inside it, and the next sample, the hit, is then further past its far edge:
up to a whole step for a band much thinner than one step (an ideal point sampler gives 1 - w/2 steps for
a band w < 1 step wide, against 1/2 for a wide one). On the floor a step is range^2 / (f h) long, so a
9 cm line 7 m away is a third of a step wide and its hits lie ~7 cm beyond it: the seed recordings'
hits on lines 6-8 m away sat +7 cm past the modelled edge at the true pose, on the outer floor's far
edge at the same ranges they did not (docs/localizer.md, "Thin-band bias").

The fit therefore expects a hit on a band of width w steps (measured along the edge normal) to lie
`offset(w)` steps past the far edge, `offset` a piecewise-linear curve through calibrated knots
(FitConfig.band_bias_widths / band_bias_samples). `calibrate` measures it from labelled frames: the
median residual in steps per band-width bin, at the true poses. Both code paths apply it: `offset_m`
here for the numpy fit, `band_offset` in fit_kernel.c (tested equal).
"""
from __future__ import annotations

from typing import Iterable

import numpy as np

from courtloc.localizer.config import FitConfig
from courtloc.localizer.court_field import CourtField, is_thin_band
from courtloc.localizer.projection import ProjectedHits

# Bins of band width in steps for the calibration; their centres become the knots. Past 4 steps a band
# behaves as a wide one (edge_offset_px covers it).
BIN_EDGES = (0.25, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0)
MIN_HITS_PER_BIN = 50


def offset_m(half_width: np.ndarray, step_normal_m: np.ndarray, cfg: FitConfig) -> np.ndarray:
    """Expected distance (m) of a hit past its band's far edge beyond the wide-band offset: half_width is
    the band's (court_field.band_half_width), step_normal_m one scan step's floor length along the edge
    normal (0: unknown -> 0)."""
    width_steps = 2.0 * half_width / np.maximum(step_normal_m, 1e-9)
    offset = np.interp(width_steps, cfg.band_bias_widths, cfg.band_bias_samples) * step_normal_m
    return np.where(is_thin_band(half_width), offset, 0.0)


def band_samples(field: CourtField, hits: ProjectedHits, pose: np.ndarray,
                 cfg: FitConfig) -> tuple[np.ndarray, np.ndarray]:
    """(band width in steps, residual in steps) of the usable thin-band hits of one frame at `pose`, with
    the band bias off: what `calibrate` bins."""
    # residuals imports fit, which imports this module for offset_m: imported at call time, no cycle.
    from courtloc.localizer.residuals import residuals_at

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

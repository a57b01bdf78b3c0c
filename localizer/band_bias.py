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
(FitConfig.band_bias_widths / band_bias_samples). `courtloc.lab.band_bias_calibration` measures it from labelled
frames: the median residual in steps per band-width bin, at the true poses. Both code paths apply it: `offset_m`
here for the numpy fit, `band_offset` in fit_kernel.c (tested equal).
"""
from __future__ import annotations

import numpy as np

from courtloc.localizer.config import FitConfig
from courtloc.localizer.court_field import is_thin_band


def offset_m(half_width: np.ndarray, step_normal_m: np.ndarray, cfg: FitConfig) -> np.ndarray:
    """Expected distance (m) of a hit past its band's far edge beyond the wide-band offset: half_width is
    the band's (court_field.band_half_width), step_normal_m one scan step's floor length along the edge
    normal (0: unknown -> 0)."""
    width_steps = 2.0 * half_width / np.maximum(step_normal_m, 1e-9)
    offset = np.interp(width_steps, cfg.band_bias_widths, cfg.band_bias_samples) * step_normal_m
    return np.where(is_thin_band(half_width), offset, 0.0)

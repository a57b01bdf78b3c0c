"""Python side of the compiled pose fit (fit_kernel.c, built by `pip install` as an optional extension).

`fit.fit_poses` calls `run` when the extension was built; without a C compiler at install time it is
absent and the numpy implementation in fit.py (the reference the kernel is tested against) is used.
The field's float32 grids are handed to C once per CourtField (buffer protocol, no copy); the hits go
as their packed array (projection.PACKED_COLUMNS).
"""
from __future__ import annotations

import logging
import math
import weakref

import numpy as np

from courtloc.localizer.config import FitConfig
from courtloc.localizer.court_field import THIN_BAND_HALF_WIDTH_M, CourtField
from courtloc.localizer.projection import ProjectedHits

log = logging.getLogger(__name__)

try:
    from courtloc.localizer import _fit_kernel
except ImportError:  # built without a compiler: fit.py falls back to numpy
    _fit_kernel = None
    # Module import runs once per process, so this says it once.
    log.warning("compiled fit kernel not built (no C compiler at install?): using the numpy fit, several "
                "times slower")

# Columns of the kernel's (S, OUT_COLUMNS) result rows.
PARAMS, COST, N_INLIERS, RMS, POS_STD, YAW_STD, COV, COV_OK = slice(0, 5), 5, 6, 7, 8, 9, slice(10, 19), 19
OUT_COLUMNS = 20


def available() -> bool:
    return _fit_kernel is not None


# id(field) -> (weak reference to the field, its C view): kept beside the fields, not on them, so that a
# CourtField stays a plain (picklable) dataclass; an entry goes when its field does.
_fields: dict[int, tuple[weakref.ref, object]] = {}


def kernel_field(field: CourtField):
    """The C view of the field's grids (None: not float32 C-contiguous, use numpy), made once per field:
    the grids (~7 MB each) are handed over by the buffer protocol, never copied."""
    entry = _fields.get(id(field))
    if entry is not None and entry[0]() is field:
        return entry[1]
    ny, nx = field.values.shape
    try:
        kf = _fit_kernel.Field(field.values, field.half_width, ny, nx, field.x0, field.y0, field.resolution)
    except (ValueError, BufferError) as exc:
        log.info("court field not usable by the fit kernel (%s): numpy fit for it", exc)
        kf = None
    key = id(field)
    _fields[key] = (weakref.ref(field, lambda _, key=key: _fields.pop(key, None)), kf)
    return kf


def run(kfield, hits: ProjectedHits, starts: np.ndarray, cfg: FitConfig, inlier_sigmas: float,
        iterations: int) -> np.ndarray:
    """The whole robust fit of every start (as fit.fit_poses) on `kfield` = kernel_field(field); needs >= 3
    hits. Returns (S, OUT_COLUMNS)."""
    tilt = cfg.tilt_sigma_deg > 0
    prior = 1.0 / math.radians(cfg.tilt_sigma_deg) ** 2 if tilt else 0.0
    config = (cfg.pixel_sigma, cfg.floor_sigma_m, cfg.range_sigma, prior, cfg.tukey_c, cfg.huber_c,
              cfg.huber_iterations, iterations, cfg.max_residual_m, cfg.gate_cos, cfg.step_tol_m, inlier_sigmas,
              tilt, tuple(cfg.band_bias_widths), tuple(cfg.band_bias_samples), THIN_BAND_HALF_WIDTH_M)
    out = np.empty((len(starts), OUT_COLUMNS))
    packed = hits.packed
    if not packed.flags.c_contiguous:  # e.g. a slice of another frame's hits
        packed = np.ascontiguousarray(packed)
    cam = hits.camera_xy
    _fit_kernel.fit(kfield, packed, cam.real, cam.imag, float(hits.camera_height),
                    np.ascontiguousarray(starts, np.float64), out, config)
    return out

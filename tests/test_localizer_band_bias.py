"""The thin-band bias (localizer/band_bias.py): the band lookup, the offset curve, its calibration.

The kernel and numpy fits applying it identically is in test_localizer_kernel.py (variant band_bias).
"""
from __future__ import annotations

import numpy as np
import pytest
from localizer_kit import twin_setup
from pydantic import ValidationError

from courtloc.lab import band_bias_calibration
from courtloc.localizer import band_bias
from courtloc.localizer.config import FitConfig, LocalizerConfig
from courtloc.localizer.court_field import THIN_BAND_HALF_WIDTH_M

# Where the twin's rendered frames see thin lines from a few to ~9 m away.
POSES = [(-1.0, 0.3, 0.1), (-2.0, -1.0, -0.2), (0.5, 2.0, 0.3), (-3.0, 0.0, 0.0), (1.0, -2.5, 2.9), (2.0, 1.0, 3.1)]


@pytest.fixture(scope="module")
def twin():
    return twin_setup(POSES)


def test_band_half_width_names_the_band_a_hit_belongs_to(twin):
    _, _, localizer, _, _ = twin
    field = localizer.field
    centre_half = 0.087 / 2  # the seed court's centre line
    x = np.array([0.0, 0.0435 + 0.03, -0.0435 - 0.2, 6.5, 9.1, -1.5])
    y = np.array([0.0, 1.0, -2.0, 0.0, 0.0, -2.0])
    hw = field.nearest(x, y, field.half_width)
    # Inside the line and beside it (either side, within 1 m): the line's half-width, to a grid cell.
    np.testing.assert_allclose(hw[:3], centre_half, atol=0.011)
    assert hw[3] >= THIN_BAND_HALF_WIDTH_M  # inside the wide outer floor: wide, whatever its exact value
    assert hw[4] == 0.0  # past the outer floor's far edge: the nearest paint is wide, no thin-band bias
    assert hw[5] == 0.0  # over 1 m from any paint: no band


def test_offset_is_the_curve_times_the_step_and_only_for_thin_bands():
    cfg = FitConfig(band_bias_widths=[0.5, 1.0, 2.0], band_bias_samples=[0.6, 0.4, 0.0])
    hw = np.array([0.05, 0.05, 0.05, 0.05, 0.05, 0.5, 0.0])
    step = np.array([0.2, 0.1, 0.05, 0.01, 0.0, 0.2, 0.2])
    # width in steps: 0.5, 1, 2, 10 -> 0.6, 0.4, 0.0, 0.0 steps; unknown step, wide band, no band -> 0
    expected = np.array([0.6 * 0.2, 0.4 * 0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(band_bias.offset_m(hw, step, cfg), expected, atol=1e-15)
    # Between knots: linear (w = 0.1 / 0.0667 = 1.5 steps -> 0.2 steps); below the first: the first value.
    np.testing.assert_allclose(band_bias.offset_m(np.array([0.05, 0.01]), np.array([0.1 / 1.5, 0.1]), cfg),
                               [0.2 * 0.1 / 1.5, 0.6 * 0.1])


def test_knots_are_validated_by_name():
    with pytest.raises(ValidationError, match="band_bias_widths"):
        LocalizerConfig.model_validate({"fit": {"band_bias_widths": [1.0, 2.0], "band_bias_samples": [0.5]}})
    with pytest.raises(ValidationError, match="band_bias_widths"):
        FitConfig(band_bias_widths=[2.0, 1.0], band_bias_samples=[0.5, 0.1])
    with pytest.raises(ValidationError, match="band_bias_widths"):
        FitConfig(band_bias_widths=[1.0], band_bias_samples=[0.5])
    assert FitConfig().band_bias_widths == []  # off unless calibrated


def test_rendered_thin_bands_put_their_hits_further_out(twin):
    """The effect is the scan's, not one renderer's: the twin's own renders show it too (its size differs
    from Gazebo's, which is why it is calibrated per data source)."""
    _, _, localizer, projector, raw = twin
    widths, offsets = [], []
    for pose, h in raw.items():
        w, off = band_bias_calibration.band_samples(localizer.field, projector.project(h[:, 0], h[:, 1]), np.array(pose),
                                        localizer.config.fit)
        widths.append(w)
        offsets.append(off)
    w, off = np.concatenate(widths), np.concatenate(offsets)
    thin, wide = (w < 0.75), (w >= 2.0) & (w < 3.0)
    assert thin.sum() >= 30 and wide.sum() >= 30
    assert np.median(off[thin]) - np.median(off[wide]) > 0.2


def test_seed_bias_calibrated_on_one_recording_holds_on_the_other(seed_dir):
    from courtloc.lab.seed_frames import load_seed_frames
    from courtloc.localizer.court_field import CourtField
    from courtloc.localizer.projection import FloorProjector
    from courtloc.world.camera import load_camera
    from courtloc.world.court import load_court

    frames = load_seed_frames(seed_dir, step=5)
    court, camera = load_court("seed-gazebo"), load_camera("seed-gazebo")
    cfg = LocalizerConfig()
    field = CourtField.from_court(court, cfg.field_resolution_m)
    projector = FloorProjector(camera, cfg.edge_offset_px, cfg.max_range_m)

    def pairs(recording):
        return [(projector.project(h[:, 0], h[:, 1]), t) for h, t, r in
                zip(frames.hits, frames.truth, frames.recordings) if r == recording]

    widths, samples = band_bias_calibration.calibrate(field, pairs("20250622"), cfg.fit)
    assert len(widths) >= 4 and samples[0] > 0.3  # lines under a step wide: hits ~half a step further out
    w, off = (np.concatenate(a) for a in zip(*(band_bias_calibration.band_samples(field, hits, truth, cfg.fit)
                                                 for hits, truth in pairs("20250625"))))
    corrected = off - np.interp(w, widths, samples)
    for lo, hi in zip(band_bias_calibration.BIN_EDGES[:2], band_bias_calibration.BIN_EDGES[1:3]):  # the bands under a step wide
        sel = (w >= lo) & (w < hi)
        assert sel.sum() >= 100
        # Most of it, not all: hits of one frame share their lines, so a fifth of the frames measures a
        # bin's median to ~0.1-0.2 steps (all frames: 0.56 / 0.54 steps in the first bin, see docs).
        assert np.median(off[sel]) > 0.3 and abs(np.median(corrected[sel])) < 0.5 * np.median(off[sel])

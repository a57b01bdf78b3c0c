"""Batched pose fits: several starts in one set of numpy calls must give what each start gives alone."""
from __future__ import annotations

import numpy as np
import pytest
from localizer_kit import assert_fits_agree, converged_fit_tolerance, rounding_tolerances, twin_setup

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.fit import fit_pose, fit_poses
from courtloc.localizer.geometric import GeometricLocalizer

POSES = [(2.0, 1.0, 0.3), (4.5, -2.0, 2.0), (-1.0, -2.0, 0.5)]


@pytest.fixture(scope="module")
def setup():
    court, camera, localizer, projector, raw = twin_setup(POSES)
    frames = {pose: projector.project(hits[:, 0], hits[:, 1]) for pose, hits in raw.items()}
    return court, camera, localizer, frames


@pytest.mark.parametrize("tilt", [0.1, 0.0])
def test_batched_starts_equal_single_fits(setup, tilt):
    _, _, localizer, frames = setup
    cfg = LocalizerConfig()
    cfg.fit.tilt_sigma_deg = tilt
    for pose, hits in frames.items():
        p = np.array(pose)
        # Near, turned either way, and far off (stops at a different iteration than the others).
        starts = np.array([p + (0.04, -0.03, 0.01), p + (0, 0, 0.15), p + (0, 0, -0.15), p + (0.6, 0.4, 0.3)])
        batched = fit_poses(localizer.field, hits, starts, cfg.fit, cfg.quality)
        assert len(batched) == len(starts)
        singles = [fit_pose(localizer.field, hits, start, cfg.fit, cfg.quality) for start in starts]
        # Batched matrix products may sum in another order than single ones: rounding-level differences,
        # bounded by what the fit itself can promise (localizer_kit.rounding_tolerances).
        assert_fits_agree(singles, batched, rounding_tolerances(localizer.field, hits, starts, cfg.fit, cfg.quality,
                                                                None, singles))
        # The near start must actually have converged onto the true pose (the batch is not a no-op).
        assert np.hypot(*(batched[0].pose[:2] - p[:2])) < 0.03 and batched[0].valid


def test_sequential_and_batched_tracking_agree(setup):
    court, camera, localizer, frames = setup
    sequential = GeometricLocalizer(court, camera, localizer.config, field=localizer.field, batch_starts=False)
    for pose, hits in frames.items():
        prev = np.array(pose) + (0.05, 0.05, 0.03)
        a, b = localizer.localize(hits, prev), sequential.localize(hits, prev)
        assert a.valid == b.valid and a.mode == b.mode == "track"
        tol = converged_fit_tolerance(a.fit, localizer.config.fit.max_iterations)
        np.testing.assert_allclose(a.pose, b.pose, rtol=0, atol=tol)


def test_grid_lookup_matches_metric_lookup_and_nearest(setup):
    _, _, localizer, _ = setup
    field = localizer.field
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-7, 7, 500), rng.uniform(-5, 5, 500)
    inv = 1.0 / field.resolution
    value, gx, gy, cell = field.lookup_grid((x - field.x0) * inv, (y - field.y0) * inv)
    v2, gx2, gy2 = field.lookup(x, y)
    np.testing.assert_allclose(value, v2)
    np.testing.assert_allclose(gx * inv, gx2)
    np.testing.assert_allclose(gy * inv, gy2)
    np.testing.assert_array_equal(cell.nearest(field.half_width), field.nearest(x, y, field.half_width))
    # Bilinear value against the grid samples: at sample points the lookup returns the sample itself.
    jx, iy = rng.integers(5, field.values.shape[1] - 5, 50), rng.integers(5, field.values.shape[0] - 5, 50)
    at, _, _, _ = field.lookup_grid(jx.astype(float), iy.astype(float))
    np.testing.assert_allclose(at, field.values[iy, jx])

"""The compiled per-frame path (localizer/fit_kernel.c) against its numpy reference (fit.py, projection.py).

Tolerances: the kernel follows the numpy code operation by operation, but sums the normal matrix in its
own order (numpy uses BLAS, whose order depends on the CPU and the BLAS build), uses sqrt(x^2 + y^2) and
one reciprocal for hypot and two divisions, and gets the tilted floor point's tan from the untilted one by
the addition formula (see fit_kernel.c). Those differ by a few ulp per operation; how far that moves a fit
depends on the fit: a converged start barely, a start still far off after its last step amplifies it
through every step (1.2e-9 m seen on one start here, where converged ones differ by ~1e-14 m). So each
start's tolerance is derived from the problem (localizer_kit.rounding_tolerances: the numpy fit's own
response to rounding-size moves of its start), and checked to stay far below a real divergence (a
different weight, gate or stopping decision moves a pose by millimetres or more).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from localizer_kit import assert_fits_agree, converged_fit_tolerance, rounding_tolerances, twin_setup

from courtloc.localizer import fit_kernel
from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.fit import fit_poses, kernel_active, kernel_enabled
from courtloc.localizer.projection import lookup_table

pytestmark = pytest.mark.skipif(not fit_kernel.available(), reason="compiled fit kernel not built (no C compiler)")

POSES = [(2.0, 1.0, 0.3), (4.5, -2.0, 2.0), (-1.0, -2.0, 0.5), (1.0, 3.0, -1.2), (5.5, 0.5, 3.0), (-3.0, 3.5, -2.6)]


@pytest.fixture(scope="module")
def setup():
    return twin_setup(POSES)


def _parallel_only(court, localizer):
    """Hits on one straight edge only: a degenerate frame (one position direction unconstrained)."""
    pose = (1.0, 2.5, math.pi / 2)
    pts, nrm = court.white_edges(0.05)
    sel = (nrm[:, 1] > 0.9) & (np.abs(pts[:, 1] - 5.99) < 0.01) & (np.abs(pts[:, 0] - 1.0) < 3.0)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    d = pts[sel] - pose[:2]
    return pose, localizer.geometry.from_points(np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]]))


@pytest.mark.parametrize("variant", ["default", "no_tilt", "range_sigma", "all_huber", "few_iterations",
                                     "band_bias"])
def test_kernel_fit_equals_numpy_fit(setup, variant):
    court, _, localizer, projector, raw = setup
    cfg = LocalizerConfig()
    iterations = None
    if variant == "no_tilt":
        cfg.fit.tilt_sigma_deg = 0.0
    elif variant == "range_sigma":
        cfg.fit.range_sigma = 0.004
        cfg.fit.tilt_sigma_deg = 0.3
    elif variant == "all_huber":
        cfg.fit.huber_iterations = 10
    elif variant == "few_iterations":
        iterations = 2
    elif variant == "band_bias":  # knots below, between and above the widths the frames' bands have
        cfg.fit.band_bias_widths = [0.5, 1.0, 1.5, 3.0]
        cfg.fit.band_bias_samples = [0.6, 0.5, 0.2, -0.1]
    rng = np.random.default_rng(7)
    frames = [(np.array(p), projector.project(h[:, 0], h[:, 1])) for p, h in raw.items()]
    pose, degenerate = _parallel_only(court, localizer)
    frames.append((np.array(pose), degenerate))
    n_valid = n_moved = 0
    for pose, hits in frames:
        # Near, turned, far off (different stopping iterations) and a batch of random ones.
        starts = np.vstack([pose + (0.04, -0.03, 0.01), pose + (0, 0, 0.15), pose + (0, 0, -0.15),
                            pose + (0.6, 0.4, 0.3), pose + rng.normal(0, [0.2, 0.2, 0.1], (4, 3))])
        with kernel_enabled(False) as on:
            assert not on
            ref = fit_poses(localizer.field, hits, starts, cfg.fit, cfg.quality, iterations)
        with kernel_enabled(True) as on:
            assert on
            got = fit_poses(localizer.field, hits, starts, cfg.fit, cfg.quality, iterations)
        assert_fits_agree(ref, got, rounding_tolerances(localizer.field, hits, starts, cfg.fit, cfg.quality,
                                                        iterations, ref))
        n_valid += sum(r.valid for r in ref)
        if cfg.fit.band_bias_widths:  # the bias must be in play, not a no-op both paths agree on
            plain = fit_poses(localizer.field, hits, starts, LocalizerConfig().fit, cfg.quality, iterations)
            n_moved += max(abs(a.pose[0] - b.pose[0]) + abs(a.pose[1] - b.pose[1]) for a, b in zip(ref, plain)) > 1e-4
    assert n_valid >= len(frames)  # the comparison covers converged fits, not only failures
    assert n_moved >= (len(frames) - 1 if cfg.fit.band_bias_widths else 0)
    # The degenerate frame: invalid, with the huge position std the normal matrix implies, in both paths.
    assert not got[0].valid and got[0].position_std_m > cfg.quality.max_position_std_m


def test_covariance_is_the_pose_block_behind_the_stds(setup):
    _, _, localizer, projector, raw = setup
    cfg = localizer.config
    pose = np.array(POSES[0])
    hits = projector.project(raw[POSES[0]][:, 0], raw[POSES[0]][:, 1])
    for enabled in (False, True):
        with kernel_enabled(enabled):
            res = fit_poses(localizer.field, hits, pose[None], cfg.fit, cfg.quality)[0]
        cov = res.covariance
        assert res.valid and cov.shape == (3, 3)
        np.testing.assert_allclose(cov, cov.T, rtol=1e-9, atol=1e-18)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
        assert math.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1]) == pytest.approx(res.position_std_m, rel=1e-9)
        assert math.sqrt(cov[2, 2]) == pytest.approx(res.yaw_std_rad, rel=1e-9)
    # Too few hits: no fit, no covariance.
    few = fit_poses(localizer.field, localizer.geometry.from_points(np.zeros((2, 2))), pose[None], cfg.fit,
                    cfg.quality)[0]
    assert few.covariance is None and not few.valid


def test_hit_geometry_equals_table_lookup_and_numpy_geometry(setup):
    _, camera, localizer, projector, raw = setup
    hits = np.vstack([h for h in raw.values()] + [np.array([[-3, 5, 0, 0], [camera.height, 10, 0, 0],
                                                            [10, camera.width, 0, 0], [100, 100, 0, 0]])])
    hits = np.ascontiguousarray(hits[:, :4], np.int16)
    ref = localizer.geometry.from_points(lookup_table(projector.table, camera.width, camera.height, hits[:, 0],
                                                      hits[:, 1]), hits[:, 0], hits[:, 1])
    got = localizer.geometry.from_table(projector.table, hits)
    assert len(got) == len(ref) and len(ref) < len(hits) - 3  # out of image / above the horizon dropped
    np.testing.assert_allclose(got.packed, ref.packed, rtol=1e-13, atol=1e-15)
    assert np.all(got.step_m > 0)  # every hit seeing floor knows its scan step
    np.testing.assert_array_equal(got.points, ref.points)
    np.testing.assert_array_equal(got.cview, ref.view_dirs[:, 0] + 1j * ref.view_dirs[:, 1])


def test_predictor_paths_agree_and_use_the_onnx_table():
    from courtloc.lab.eval import default_model_path
    from courtloc.localizer.predictor import load_predictor
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer

    predictor = load_predictor(default_model_path())
    w, h = predictor.width, predictor.height
    hits = scan_hits(Renderer(predictor.package.court, predictor.package.camera).render(POSES[1]))
    # The table the compiled path reads is the ONNX graph's own (same points, NaN where it has none).
    onnx_pts = predictor.floor_points(hits)
    table_pts = lookup_table(predictor.floor_table, w, h, hits[:, 0], hits[:, 1])
    np.testing.assert_array_equal(onnx_pts, table_pts)
    with kernel_enabled(False):
        ref_track = predictor.predict(hits, w, h, previous=POSES[1])
        ref_cold = predictor.predict(hits, w, h)
        # Both answers converge on this frame's one solution: its conditioning bounds the rounding.
        fit = predictor.localizer.localize(predictor.projected_hits(hits), np.array(POSES[1])).fit
    tol = converged_fit_tolerance(fit, predictor.localizer.config.fit.max_iterations)
    assert kernel_active()
    for ref, got in ((ref_track, predictor.predict(hits, w, h, previous=POSES[1])), (ref_cold, predictor.predict(hits, w, h))):
        assert got.valid and (got.mode, got.n_hits, got.n_inliers) == (ref.mode, ref.n_hits, ref.n_inliers)
        np.testing.assert_allclose([got.x, got.y, got.yaw], [ref.x, ref.y, ref.yaw], rtol=0, atol=tol)
    empty = predictor.predict(np.zeros((0, 4), np.int16), w, h, previous=POSES[1])
    assert not empty.valid and empty.n_hits == 0


def test_dispatch_and_fallbacks(setup, monkeypatch):
    _, _, localizer, projector, raw = setup
    cfg = localizer.config
    hits = projector.project(raw[POSES[2]][:, 0], raw[POSES[2]][:, 1])
    start = np.array(POSES[2])[None]
    ref = fit_poses(localizer.field, hits, start, cfg.fit, cfg.quality)

    def boom(*args, **kwargs):
        raise AssertionError("kernel called")

    monkeypatch.setattr(fit_kernel, "run", boom)
    with pytest.raises(AssertionError, match="kernel called"):
        fit_poses(localizer.field, hits, start, cfg.fit, cfg.quality)
    with kernel_enabled(False):
        fit_poses(localizer.field, hits, start, cfg.fit, cfg.quality)  # numpy: no kernel call
    monkeypatch.undo()
    # A field the kernel cannot read as it is (float64 grid) falls back to numpy: the numpy answer exactly.
    f64 = dataclasses.replace(localizer.field, values=localizer.field.values.astype(np.float64))
    assert fit_kernel.kernel_field(f64) is None
    with kernel_enabled(False):
        ref64 = fit_poses(f64, hits, start, cfg.fit, cfg.quality)[0]
    got64 = fit_poses(f64, hits, start, cfg.fit, cfg.quality)[0]
    assert got64.cost == ref64.cost and np.array_equal(got64.pose, ref64.pose)
    assert np.hypot(*(got64.pose[:2] - ref[0].pose[:2])) < 1e-3  # float64 grid arithmetic: nearly the same


def test_kernel_rejects_malformed_buffers(setup):
    _, _, localizer, projector, raw = setup
    kernel = fit_kernel._fit_kernel
    kf = fit_kernel.kernel_field(localizer.field)
    hits = projector.project(raw[POSES[0]][:, 0], raw[POSES[0]][:, 1])
    cfg = localizer.config.fit
    config = (cfg.pixel_sigma, cfg.floor_sigma_m, cfg.range_sigma, 1.0, cfg.tukey_c, cfg.huber_c,
              cfg.huber_iterations, 6, cfg.max_residual_m, cfg.gate_cos, cfg.step_tol_m, 3.0, True, (), (), 0.1)
    starts = np.zeros((2, 3))
    with pytest.raises(ValueError, match="hits"):
        kernel.fit(kf, hits.packed[:, :11].copy(), 0.0, 0.0, 1.0, starts, np.empty((2, 20)), config)
    with pytest.raises(ValueError, match="out"):
        kernel.fit(kf, hits.packed, 0.0, 0.0, 1.0, starts, np.empty((1, 20)), config)
    with pytest.raises(ValueError, match="out"):
        kernel.fit(kf, hits.packed, 0.0, 0.0, 1.0, starts, np.empty((2, 20), np.float32), config)
    with pytest.raises(TypeError):
        kernel.fit(kf, hits.packed, 0.0, 0.0, 1.0, starts, np.empty((2, 20)), config[:-1])
    with pytest.raises(ValueError, match="values"):
        kernel.Field(np.zeros((4, 4)), None, 4, 4, 0.0, 0.0, 0.01)
    with pytest.raises(ValueError, match="band-bias"):  # unequal knot tuples
        kernel.fit(kf, hits.packed, 0.0, 0.0, 1.0, starts, np.empty((2, 20)), config[:13] + ((1.0, 2.0), (0.5,), 0.1))
    with pytest.raises(ValueError, match="increase"):
        kernel.fit(kf, hits.packed, 0.0, 0.0, 1.0, starts, np.empty((2, 20)),
                   config[:13] + ((2.0, 1.0), (0.5, 0.1), 0.1))
    steps = np.zeros(16, np.float32)
    with pytest.raises(ValueError, match="table"):
        kernel.hit_geometry(np.zeros((10, 2), np.float32), steps, 4, 4, np.zeros((1, 4), np.int16), 0.0, 0.0, 1.0,
                            0.0, 0.0, 1.0, 1.0, np.empty((1, 12)))
    with pytest.raises(ValueError, match="steps"):
        kernel.hit_geometry(np.zeros((16, 2), np.float32), steps[:10], 4, 4, np.zeros((1, 4), np.int16), 0.0, 0.0,
                            1.0, 0.0, 0.0, 1.0, 1.0, np.empty((1, 12)))

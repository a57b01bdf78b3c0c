"""Shared set-up of the localizer tests: the seed twin's court, camera, localizer and rendered frames."""
from __future__ import annotations

from courtloc.localizer.geometric import GeometricLocalizer
from courtloc.localizer.projection import FloorProjector
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court


def twin_setup(poses):  # noqa: ANN001, ANN201
    """(court, camera, localizer, projector, {pose: radial-scan hits of the rendered frame})."""
    from courtloc.sim.edges import scan_hits
    from courtloc.sim.render import Renderer

    court, camera = load_court("seed-gazebo"), load_camera("seed-gazebo")
    localizer = GeometricLocalizer(court, camera)
    renderer = Renderer(court, camera)
    projector = FloorProjector(camera, localizer.config.edge_offset_px, localizer.config.max_range_m)
    return court, camera, localizer, projector, {pose: scan_hits(renderer.render(pose)) for pose in poses}


# A divergence between two fit implementations that matters (a different weight, gate or stopping decision)
# moves a pose by millimetres; a derived rounding tolerance above this would no longer tell the two apart.
MEANINGFUL_DIVERGENCE_M = 1e-4


def rounding_tolerances(field, hits, starts, cfg, quality, iterations, ref):  # noqa: ANN001, ANN201
    """Per start, how far a second correct implementation of the fit may land from `ref` (the numpy fit's
    results) through floating-point rounding alone, for every number a FitResult carries.

    Two implementations that sum the n hits' terms in different orders differ by up to n * eps relative in
    each normal-matrix entry (the worst-case bound of a recursive sum), in every iteration. How much such a
    difference moves the result is the fit's own sensitivity: well-conditioned converged fits barely move,
    a start still far off after its last step amplifies it through every step, by a factor no constant can
    promise across CPUs and BLAS builds. So it is measured here, on this machine: the numpy fit is run
    again from starts moved by n * eps * (1 + |start|) (three sign patterns), and the tolerance of each
    quantity is `iterations` times the larger of that response and n * eps * |value| (a difference enters
    in every step, each propagating at most like one from the start). Returns one dict per start:
    quantity -> absolute tolerance of its largest entry's difference.
    """
    import numpy as np

    from courtloc.localizer.fit import fit_poses, kernel_enabled

    starts = np.atleast_2d(np.asarray(starts, np.float64))
    n_starts, n = len(starts), max(len(hits), 1)
    eps = np.finfo(np.float64).eps
    steps = iterations or cfg.max_iterations
    signs = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1]], np.float64)
    moved = np.vstack([starts + s * n * eps * (1 + np.abs(starts)) for s in signs])
    with kernel_enabled(False):
        perturbed = fit_poses(field, hits, moved, cfg, quality, iterations)

    def values(r) -> dict:  # noqa: ANN001
        out = {"pose": np.asarray(r.pose), "tilt": np.asarray(r.tilt)}
        out.update({k: np.float64(getattr(r, k)) for k in
                    ("cost", "rms_m", "position_std_m", "yaw_std_rad", "quality")})
        if r.covariance is not None:
            out["covariance"] = np.asarray(r.covariance)
        return out

    # A residual is a difference of floor coordinates up to `reach` metres from the court's origin: its
    # rounding floor is eps * reach, whatever the pose (it matters where the residuals are noise only).
    reach = float(np.max(np.abs(hits.points))) + float(np.max(np.abs(starts[:, :2])))
    absolute = {"rms_m": n * eps * reach}
    tolerances = []
    for s in range(n_starts):
        base = values(ref[s])
        floor = dict(absolute)
        if base["rms_m"] > 0:
            # The cost is a mean of squared residuals over their scale: its relative rounding is twice the rms's.
            floor["cost"] = 2.0 * float(base["cost"]) * absolute["rms_m"] / float(base["rms_m"])
        tol = {}
        for key, value in base.items():
            response = np.zeros_like(value)
            for p in range(len(signs)):
                other = values(perturbed[p * n_starts + s]).get(key)
                if other is not None:
                    with np.errstate(invalid="ignore"):  # inf - inf where a quantity is undefined
                        response = np.maximum(response, np.nan_to_num(np.abs(other - value), posinf=0.0))
            # Norm-wise: an entry's rounding scales with the whole vector or matrix it is computed with
            # (an off-diagonal covariance term is a difference of products of the large ones).
            scale = np.max(np.nan_to_num(np.abs(value), posinf=0.0))
            tol[key] = steps * max(float(np.max(response)), n * eps * scale, floor.get(key, 0.0))
        tolerances.append(tol)
    return tolerances


def assert_fits_agree(ref, got, tolerances) -> None:  # noqa: ANN001
    """`got` equals `ref` start by start within the rounding tolerances (see rounding_tolerances);
    decisions (validity, inlier counts) exactly."""
    import numpy as np

    assert len(ref) == len(got) == len(tolerances)
    for a, b, tol in zip(ref, got, tolerances):
        assert (b.valid, b.n_inliers, b.n_hits) == (a.valid, a.n_inliers, a.n_hits)
        if a.valid:  # the derived tolerance still separates rounding from a real divergence
            assert tol["pose"] < MEANINGFUL_DIVERGENCE_M, tol["pose"]
        _within(np.asarray(b.pose) - a.pose, tol["pose"], "pose")
        _within(np.asarray(b.tilt) - np.asarray(a.tilt), tol["tilt"], "tilt")
        for key in ("cost", "rms_m", "position_std_m", "yaw_std_rad", "quality"):
            x, y = getattr(a, key), getattr(b, key)
            if np.isinf(x) or np.isinf(y):
                assert x == y, key
            else:
                assert abs(y - x) <= tol[key], (key, x, y, tol[key])
        assert (a.covariance is None) == (b.covariance is None)
        if a.covariance is not None:
            _within(b.covariance - a.covariance, tol["covariance"], "covariance")


def _within(diff, tol, what: str) -> None:  # noqa: ANN001
    import numpy as np

    assert np.all(np.abs(diff) <= tol), f"{what}: difference {np.abs(diff)} over the rounding tolerance {tol}"


def converged_fit_tolerance(fit, iterations: int) -> float:  # noqa: ANN001
    """How far two correct implementations' converged fits of one frame may differ by rounding alone (m or
    rad): in each of `iterations` steps the normal equations' entries may differ by n * eps relative (sums
    of n terms in another order), which moves their solution by up to cond(normal matrix) times that,
    relative to the pose's scale. Only for a valid fit (its covariance is the inverse normal matrix)."""
    import numpy as np

    assert fit.valid and fit.covariance is not None
    scale = 1.0 + float(np.max(np.abs(fit.pose)))
    tol = iterations * fit.n_hits * np.finfo(np.float64).eps * float(np.linalg.cond(fit.covariance)) * scale
    assert tol < MEANINGFUL_DIVERGENCE_M, tol  # still tells rounding from a real divergence
    return tol

"""The pose carries the fit's own (x, y, yaw) covariance: what ROS and Foxglove users get as
PoseWithCovariance until the motion filter's covariance is published instead."""
from __future__ import annotations

import numpy as np

from infer_models import TwinFrames, bundled_default
from courtloc.localizer.predictor import load_predictor

TRUTH = (2.0, -1.5, 0.4)


def test_prediction_covariance_is_the_fits_and_consistent_with_its_std() -> None:
    frames = TwinFrames([TRUTH])
    predictor = load_predictor(bundled_default() / "model.onnx")
    pred = predictor.predict(frames.hits[0], 640, 480)
    assert pred.valid and pred.covariance is not None and len(pred.covariance) == 9
    cov = np.array(pred.covariance).reshape(3, 3)
    np.testing.assert_allclose(cov, cov.T, rtol=1e-9, atol=0)
    assert np.all(np.linalg.eigvalsh(cov) > 0), "positive definite"
    # position_std_m is the worst direction of the same normal matrix: the largest eigenvalue of the x/y block
    worst = float(np.sqrt(np.linalg.eigvalsh(cov[:2, :2]).max()))
    assert pred.position_std_m is not None
    np.testing.assert_allclose(worst, pred.position_std_m, rtol=1e-6)

"""Eval metrics against values worked out by hand on a toy set."""
from __future__ import annotations

import math

import numpy as np
import pytest

from courtloc.lab.metrics import compute_metrics
from courtloc.world.angles import wrap_angle


def test_metrics_match_hand_computed_values() -> None:
    truth = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, -1.0], [-3.0, 2.0]])
    # errors (dx, dy): (3, 4) -> 5, (0, 0) -> 0, (-1, 0) -> 1, (0, 2) -> 2
    pred = np.array([[3.0, 4.0], [1.0, 1.0], [1.0, -1.0], [-3.0, 4.0]])
    m = compute_metrics(pred, truth)
    assert m.n == 4
    # squares: 9+16, 0+0, 1+0, 0+4 = 30 over 8 elements
    assert m.mse == pytest.approx(30 / 8)
    assert m.mae_x == pytest.approx((3 + 0 + 1 + 0) / 4)
    assert m.mae_y == pytest.approx((4 + 0 + 0 + 2) / 4)
    assert m.mean_err_m == pytest.approx((5 + 0 + 1 + 2) / 4)
    assert m.median_err_m == pytest.approx((1 + 2) / 2)
    # sorted 0,1,2,5: p95 at rank 0.95*3 = 2.85 -> 2 + 0.85*(5-2)
    assert m.p95_err_m == pytest.approx(2 + 0.85 * 3)
    assert m.yaw_median_deg is None
    assert "yaw_median_deg" not in m.as_dict()


def test_yaw_error_is_wrapped() -> None:
    truth = np.zeros((3, 2))
    true_yaw = np.radians([179.0, -170.0, 10.0])
    pred_yaw = np.radians([-179.0, 170.0, 13.0])  # errors 2, 20, 3 degrees once wrapped
    m = compute_metrics(truth, truth, pred_yaw, true_yaw)
    assert m.yaw_median_deg == pytest.approx(3.0)
    assert m.as_dict()["yaw_median_deg"] == pytest.approx(3.0)


def test_wrap_angle_range() -> None:
    wrapped = wrap_angle(np.array([math.pi, -math.pi, 3 * math.pi, 0.5]))
    assert np.all(wrapped >= -math.pi) and np.all(wrapped < math.pi)
    assert wrapped[3] == pytest.approx(0.5)


def test_shape_mismatch_is_an_error() -> None:
    with pytest.raises(ValueError):
        compute_metrics(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError):
        compute_metrics(np.zeros((0, 2)), np.zeros((0, 2)))


def test_eval_command_runs_without_torch(tmp_path) -> None:  # noqa: ANN001
    """`courtloc eval` is runtime-side: it must work with torch made unimportable."""
    import json
    import subprocess
    import sys

    import onnx

    from courtloc.localizer.manifest import InputSpec, Manifest, OutputSpec, TensorSpec, attach_manifest
    from courtloc.training import paper_onnx
    from courtloc.training.toy_data import write_toy_dataset

    data = write_toy_dataset(tmp_path / "toy", frames_per_recording=4)
    rng = np.random.default_rng(0)
    sizes = [(1024, 32 * 64), (256, 1024), (64, 256), (2, 64)]
    weights = {}
    for k, (rows, cols) in enumerate(sizes, start=1):
        weights[f"w{k}"] = (rng.standard_normal((rows, cols)) / np.sqrt(cols)).astype(np.float32)
        weights[f"b{k}"] = np.zeros(rows, np.float32)
    model = paper_onnx.build_sparse(weights)
    attach_manifest(model, Manifest(
        name="toy-sparse", version=1, court="seed-gazebo", camera="seed-gazebo",
        input=InputSpec(kind="sparse_hits", tensors=[TensorSpec(name="indices", dtype="int64", shape=["K"]),
                                                    TensorSpec(name="values", dtype="float32", shape=["K"])]),
        preprocessing={"crop_top": 16, "frame_width": 64, "frame_height": 48},
        outputs=[OutputSpec(name="xy", components=["x", "y"], units=["m", "m"])]))
    onnx.save(model, str(tmp_path / "toy.onnx"))
    out = tmp_path / "m.json"
    code = ("import sys; sys.modules['torch'] = None\n"
            "from courtloc.cli import main\n"
            f"main(['eval', '--data', {str(data)!r}, '--model', {str(tmp_path / 'toy.onnx')!r}, "
            f"'--json', {str(out)!r}, '--no-progress'])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads(out.read_text())
    assert metrics["n"] == 8 and metrics["mean_err_m"] > 0

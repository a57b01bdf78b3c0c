"""`courtloc export` ships golden inputs with the paper network, and the robot's validation judges the exported
graph on them: a small sparse graph (a few hidden units instead of 1024, the paper's 280x640 crop) whose
answer is a constant, so its golden errors are the distances from that point to the golden poses."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from extras import TORCH_MISSING

torch = pytest.importorskip("torch", reason=TORCH_MISSING)

from courtloc.lab.golden_build import GOLDEN_POSES  # noqa: E402
from courtloc.localizer.golden import load_golden, sidecar_path  # noqa: E402
from courtloc.localizer.manifest import read_manifest, sha256_of  # noqa: E402
from courtloc.services.infer.config import InferConfig  # noqa: E402
from courtloc.services.infer.sandbox import validate_in_child  # noqa: E402
from courtloc.services.infer.validation import ModelRefused  # noqa: E402
from courtloc.training.export import export_paper  # noqa: E402

ANSWER = (1.0, 0.5)


def _constant_network(path: Path) -> Path:
    hidden = [4, 4, 4, 2]
    rng = np.random.default_rng(0)
    weights = {"w1": rng.normal(0, 0.01, (hidden[0], 280 * 640)).astype(np.float32),
               "b1": np.zeros(hidden[0], np.float32)}
    for k, (n_in, n_out) in enumerate(zip(hidden, hidden[1:]), start=2):
        weights[f"w{k}"] = np.zeros((n_out, n_in), np.float32)  # the answer is the last bias alone
        weights[f"b{k}"] = np.zeros(n_out, np.float32)
    weights["b4"] = np.array(ANSWER, np.float32)
    torch.save({"weights": weights, "input_shape": [280, 640], "crop_top": 200, "summary": {}}, path)
    return path


def test_export_ships_golden_inputs_the_robot_judges(tmp_path: Path) -> None:
    model = export_paper(_constant_network(tmp_path / "model.pt"), tmp_path / "onnx", kinds=("sparse",))["sparse"]
    golden = read_manifest(model).golden
    assert golden is not None and golden.n_frames == len(GOLDEN_POSES)
    assert golden.sha256 == sha256_of(sidecar_path(model))
    frames = load_golden(sidecar_path(model))
    assert [f.pose for f in frames] == [tuple(map(float, p)) for p in GOLDEN_POSES]
    worst = max(math.hypot(ANSWER[0] - p[0], ANSWER[1] - p[1]) for p in GOLDEN_POSES)
    assert worst <= golden.max_position_error_m <= worst * 1.25 + 0.05  # stated: worst + a quarter, 5 cm steps

    folder = tmp_path / "store-version"
    folder.mkdir()
    (folder / "model.onnx").write_bytes(model.read_bytes())
    (folder / "golden.npz").write_bytes(sidecar_path(model).read_bytes())
    with pytest.raises(ModelRefused, match=r"> 0.25 m \(deployment limit max_golden_position_error_m\)"):
        validate_in_child(folder, InferConfig(store=tmp_path / "store"), pushed=False)
    lenient = InferConfig(store=tmp_path / "store", max_golden_position_error_m=10.0)
    assert f"(limit {golden.max_position_error_m:g} m)" in validate_in_child(folder, lenient, pushed=False)

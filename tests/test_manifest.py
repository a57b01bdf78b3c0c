"""Manifest round trip through a real ONNX file, and the weights hash catching a changed weight."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from courtloc.localizer.manifest import (
    InputSpec,
    Manifest,
    ManifestError,
    OutputSpec,
    TensorSpec,
    TrainingData,
    read_manifest,
    verify_weights,
    weights_sha256,
    write_manifest,
)


def _tiny_model(path: Path, weight: np.ndarray) -> None:
    graph = helper.make_graph(
        [helper.make_node("MatMul", ["x", "w"], ["xy"])], "tiny",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])],
        [helper.make_tensor_value_info("xy", TensorProto.FLOAT, [1, 2])],
        [numpy_helper.from_array(weight, "w")])
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), str(path))


def _manifest() -> Manifest:
    return Manifest(
        name="tiny", version=3,
        input=InputSpec(kind="dense_image", tensors=[TensorSpec(name="x", dtype="float32", shape=[1, 3])]),
        court="seed-gazebo-12x8", camera="seed-gazebo-f383",
        outputs=[OutputSpec(name="xy", components=["x", "y"], units=["m", "m"])],
        training_data=TrainingData(fingerprint="ab" * 32, recordings=["20250622"], n_frames=3138),
        metrics={"val": {"n": 10, "mean_err_m": 0.5}})


def test_round_trip_and_weights_hash(tmp_path: Path) -> None:
    path = tmp_path / "tiny.onnx"
    weight = np.arange(6, dtype=np.float32).reshape(3, 2)
    _tiny_model(path, weight)
    written = write_manifest(path, _manifest())
    assert len(written.weights_sha256) == 64
    back = read_manifest(path)
    assert back == written
    assert back.input.tensors[0].shape == [1, 3]
    assert back.metrics["val"]["mean_err_m"] == 0.5
    assert verify_weights(path) == written
    # the manifest is metadata only: the model still runs
    out = ort.InferenceSession(str(path)).run(None, {"x": np.ones((1, 3), np.float32)})[0]
    assert np.allclose(out, weight.sum(axis=0))
    # writing it again replaces it, it does not add a second entry
    write_manifest(path, _manifest().model_copy(update={"version": 4}))
    model = onnx.load(str(path))
    assert [p.key for p in model.metadata_props].count("courtloc.manifest") == 1
    assert read_manifest(path).version == 4


def test_changed_weights_are_detected(tmp_path: Path) -> None:
    path = tmp_path / "tiny.onnx"
    _tiny_model(path, np.ones((3, 2), np.float32))
    write_manifest(path, _manifest())
    model = onnx.load(str(path))
    before = weights_sha256(model)
    changed = np.ones((3, 2), np.float32)
    changed[1, 1] = 1.0001
    model.graph.initializer[0].CopyFrom(numpy_helper.from_array(changed, "w"))
    assert weights_sha256(model) != before
    onnx.save(model, str(path))
    with pytest.raises(ManifestError, match="does not match"):
        verify_weights(path)


def test_missing_and_bad_manifest(tmp_path: Path) -> None:
    path = tmp_path / "bare.onnx"
    _tiny_model(path, np.ones((3, 2), np.float32))
    with pytest.raises(ManifestError, match="no 'courtloc.manifest'"):
        read_manifest(path)
    model = onnx.load(str(path))
    helper.set_model_props(model, {"courtloc.manifest": '{"name": "x"}'})
    onnx.save(model, str(path))
    with pytest.raises(ManifestError, match="bad manifest"):
        read_manifest(path)
    with pytest.raises(ManifestError, match="not found"):
        read_manifest(tmp_path / "nope.onnx")


def test_bundled_package_states_the_runtime_preprocessing_and_its_data() -> None:
    from courtloc.lab.eval import default_model_path
    from courtloc.scan.config import DEFAULT_HSV_RANGES, ScanConfig

    manifest = read_manifest(default_model_path() / "model.onnx")
    pre = manifest.preprocessing
    assert [(r.lower, r.upper) for r in pre.hsv_ranges] == [(r.lower, r.upper) for r in DEFAULT_HSV_RANGES]
    assert pre.scan_step_deg == ScanConfig().angle_step_deg and (pre.frame_width, pre.frame_height) == (640, 480)
    data = manifest.training_data
    assert data is not None and len(data.fingerprint) == 64 and data.recordings == ["20250622", "20250625"]

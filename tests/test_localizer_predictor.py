"""load_predictor serves the paper network's ONNX kinds too (fed hits drawn as the dot image)."""
from __future__ import annotations

import numpy as np
import pytest

from courtloc.localizer.manifest import InputSpec, Manifest, ManifestError, OutputSpec, TensorSpec, attach_manifest
from courtloc.localizer.predictor import load_predictor

H, W = 280, 640


def _counting_dense_model(path):
    """x = number of lit pixels in the crop, y = 2 * that number: checks the feed, not a network."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    weight = np.zeros((H * W, 2), np.float32)
    weight[:, 0], weight[:, 1] = 1.0, 2.0
    graph = helper.make_graph(
        [helper.make_node("Flatten", ["image"], ["flat"], axis=1), helper.make_node("MatMul", ["flat", "w"], ["xy"])],
        "toy", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, H, W])],
        [helper.make_tensor_value_info("xy", TensorProto.FLOAT, [1, 2])],
        initializer=[numpy_helper.from_array(weight, "w")])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    attach_manifest(model, Manifest(
        name="toy-dense", version=1, court="seed-gazebo", camera="seed-gazebo",
        input=InputSpec(kind="dense_image", tensors=[TensorSpec(name="image", dtype="float32", shape=[1, H, W])]),
        outputs=[OutputSpec(name="xy", components=["x", "y"], units=["m", "m"])]))
    onnx.save(model, str(path))


def test_dense_paper_model_gets_the_dot_image_of_the_hits(tmp_path):
    path = tmp_path / "toy.onnx"
    _counting_dense_model(path)
    predictor = load_predictor(path)
    assert predictor.manifest.input.kind == "dense_image"
    hits = np.array([[300, 100, 0, 0], [400, 500, 0, 0], [50, 320, 0, 0]], np.int16)  # the last is cropped away
    pred = predictor.predict(hits, 640, 480)
    assert pred.yaw is None and pred.valid
    assert pred.x == pytest.approx(26.0)  # two radius-2 discs of 13 pixels
    assert pred.y == pytest.approx(52.0)


def test_file_without_manifest_is_refused(tmp_path):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(Exception):
        load_predictor(bad)
    with pytest.raises(ManifestError):
        load_predictor(tmp_path / "missing")


def test_geometric_predictor_tracks_with_the_motion_filter_state() -> None:
    """What the infer stage runs per frame: acquisition from the configured start decides over a few frames
    of agreement (docs/localizer.md, "Acquisition"), then frames track from the returned state."""
    from infer_models import TwinFrames

    from courtloc.lab.eval import default_model_path
    from courtloc.localizer import acquire
    from courtloc.localizer.motion import MotionState

    still = [(1.0, -0.5, 0.3)] * 6
    moving = [(1.03, -0.5, 0.31), (1.06, -0.49, 0.32)]
    frames = TwinFrames(still + moving)
    predictor = load_predictor(default_model_path())
    state: object = acquire.Acquiring(prior=acquire.Prior(source="start", pose=np.array(still[0]), std_m=0.3,
                                                          yaw_std_rad=0.2))
    decided_at = None
    for k, (pose, hits) in enumerate(zip(still + moving, frames.hits)):
        pred, state = predictor.track(hits, 640, 480, state, t=k / 30)
        if decided_at is None and pred.valid:
            decided_at = k
        if decided_at is not None:
            assert pred.valid and np.hypot(pred.x - pose[0], pred.y - pose[1]) < 0.05
            assert isinstance(state, MotionState) and state.t == pytest.approx(k / 30)
        else:
            assert pred.reason in ("ambiguous", "confirming", "searching")
    assert decided_at is not None and decided_at < len(still), "the start pose decided while the robot stood still"
    assert pred.mode == "track"
    with pytest.raises(ValueError, match="does not match"):
        predictor.track(frames.hits[0], 320, 240, state)

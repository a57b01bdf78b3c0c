"""Models and inputs for the infer service's integration tests: real ONNX files, real twin frames.

- `TwinFrames` renders the seed-gazebo twin at known poses and runs the real preprocess pipeline, so
  the test feeds the infer stage the same Edges a camera + preprocess chain would publish.
- `relabelled_package` copies the bundled geometric package under another manifest name (a valid
  second model that behaves like the default).
- `tiny_paper_model` builds a small 'dense_image' network with onnx.helper in the paper model's
  input/output contract; its knobs make the bad ones (NaN output, a graph shape the manifest does not
  state, weights that no longer match weights_sha256).
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from courtloc.common.messages import Edges, Header
from courtloc.localizer.manifest import (InputSpec, Manifest, OutputSpec, PreprocessSpec, TensorSpec,
                                         attach_manifest, read_manifest, write_manifest)
from courtloc.services.infer.service import bundled_default
from courtloc.services.preprocess.pipeline import hits_to_bytes

COURT = CAMERA = "seed-gazebo"
WIDTH, HEIGHT, CROP_TOP = 640, 480, 200


class TwinFrames:
    """Radial-scan hits of rendered twin frames, one per pose, made once."""

    def __init__(self, poses: list[tuple[float, float, float]], court: str = COURT, camera: str = CAMERA) -> None:
        from courtloc.services.preprocess.config import PreprocessConfig
        from courtloc.services.preprocess.pipeline import Preprocessor
        from courtloc.sim.camera import load_camera
        from courtloc.sim.court import load_court
        from courtloc.sim.render import Renderer

        camera_model = load_camera(camera)
        assert (camera_model.width, camera_model.height) == (WIDTH, HEIGHT)
        renderer = Renderer(load_court(court), camera_model)
        preprocessor = Preprocessor(PreprocessConfig(frame_width=WIDTH, frame_height=HEIGHT))
        self.poses = list(poses)
        self.hits = [preprocessor.process(renderer.render(pose)) for pose in self.poses]

    def edges(self, index: int, seq: int, robot_id: str = "robot1") -> Edges:
        """The Edges message of frame `index`, stamped now (fresh) as the preprocess stage would."""
        hits = self.hits[index % len(self.hits)]
        header = Header.now(robot_id, seq, "camera").forwarded("preprocess", valid=True)
        return Edges(header=header, width=WIDTH, height=HEIGHT, crop_top=CROP_TOP, n_hits=len(hits),
                     hits=hits_to_bytes(hits))


def relabelled_package(out_dir: Path, name: str, pad_bytes: int = 0) -> Path:
    """The bundled package under manifest name `name`; `pad_bytes` adds an extra file (a large push)."""
    shutil.copytree(bundled_default(), out_dir)
    manifest = read_manifest(out_dir / "model.onnx")
    write_manifest(out_dir / "model.onnx", manifest.model_copy(update={"name": name}))
    if pad_bytes:
        # Incompressible and not all zeros, so no layer can shortcut the bytes.
        rng = np.random.default_rng(len(name))
        (out_dir / "padding.bin").write_bytes(rng.bytes(pad_bytes))
    return out_dir


def tiny_paper_model(path: Path, name: str, xy: tuple[float, float] = (1.0, 0.5), gain: float = 1e-5,
                     graph_rows: int | None = None, nan: bool = False, corrupt_after_manifest: bool = False) -> Path:
    """A 'dense_image' model: xy = sum(image) * gain + bias (on the court for any twin frame).

    graph_rows: the graph's input height when it must differ from the manifest's (280).
    nan: the gain is NaN, so every output is NaN.
    corrupt_after_manifest: a bias changed after the manifest recorded the weights' sha256.
    """
    rows = HEIGHT - CROP_TOP
    graph_shape = [1, graph_rows or rows, WIDTH]
    gain_value = float("nan") if nan else gain
    inits = [numpy_helper.from_array(np.array([1, 2], np.int64), "sum_axes"),
             numpy_helper.from_array(np.full((1, 2), gain_value, np.float32), "gain"),
             numpy_helper.from_array(np.array([xy], np.float32), "bias")]
    nodes = [helper.make_node("ReduceSum", ["image", "sum_axes"], ["total"], keepdims=1),
             helper.make_node("Reshape", ["total", "one_by_one"], ["total_2d"]),
             helper.make_node("Mul", ["total_2d", "gain"], ["scaled"]),
             helper.make_node("Add", ["scaled", "bias"], ["xy"])]
    inits.append(numpy_helper.from_array(np.array([1, 1], np.int64), "one_by_one"))
    graph = helper.make_graph(nodes, "tiny_paper",
                              [helper.make_tensor_value_info("image", TensorProto.FLOAT, graph_shape)],
                              [helper.make_tensor_value_info("xy", TensorProto.FLOAT, [1, 2])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    onnx.checker.check_model(model)
    manifest = Manifest(
        name=name, version=1,
        input=InputSpec(kind="dense_image",
                        tensors=[TensorSpec(name="image", dtype="float32", shape=[1, rows, WIDTH])]),
        preprocessing=PreprocessSpec(frame_width=WIDTH, frame_height=HEIGHT, crop_top=CROP_TOP),
        court=COURT, camera=CAMERA, outputs=[OutputSpec(name="xy", components=["x", "y"], units=["m", "m"])])
    attach_manifest(model, manifest)
    if corrupt_after_manifest:
        bias = next(t for t in model.graph.initializer if t.name == "bias")
        bias.CopyFrom(numpy_helper.from_array(np.array([[xy[0] + 0.25, xy[1]]], np.float32), "bias"))
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, str(path))
    return path


def truncated_copy(source: Path, path: Path, keep: float = 0.5) -> Path:
    data = source.read_bytes()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data[: int(len(data) * keep)])
    return path


class Pacer:
    """Ticks at a fixed rate on the monotonic clock (a stream's cadence, not a synchronisation)."""

    def __init__(self, hz: float) -> None:
        self.period = 1.0 / hz
        self.next = time.monotonic()

    def wait(self, stop) -> bool:  # noqa: ANN001 - threading.Event
        """Wait for the next tick; False once `stop` is set."""
        self.next += self.period
        return not stop.wait(max(0.0, self.next - time.monotonic()))


def request_pose(client, frames: TwinFrames, seq: int, frame_index: int = 0):  # noqa: ANN001, ANN201
    """Publish twin frame `frame_index` as edges `seq` to a running infer stage and return its pose."""
    from courtloc.common import codec

    client.wait_subscribed("preprocess/edges")  # a put before the stage's route exists reaches nobody
    client.put_raw("preprocess/edges", codec.encode(frames.edges(frame_index, seq)))
    return client.wait_for("infer/pose", lambda p: p.header.seq == seq, timeout=10.0)


def first_valid_pose(client, frames: TwinFrames, seq: int, most: int = 8):  # noqa: ANN001, ANN201
    """Frames `seq`, `seq + 1`, ... until a valid pose, at most `most` (then the last pose, invalid): a fresh
    stage acquires its pose over a few frames (docs/localizer.md, "Acquisition"). Returns (pose, next seq)."""
    for k in range(most):
        pose = request_pose(client, frames, seq + k)
        if pose.header.valid:
            break
    return pose, seq + k + 1


def run_model_cli(config: Path, *args: str) -> tuple[int, dict, str]:
    """`courtloc -v model ARGS --config CONFIG --json` as its own process, niced: the pit is another machine.

    Returns (exit code, the robot's reply as JSON, the log on stderr).
    """
    import json
    import subprocess

    from buskit import PYTHON

    done = subprocess.run(["nice", "-n", "10", *PYTHON, "-v", "model", *args, "--config", str(config), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert done.stdout, done.stderr
    return done.returncode, json.loads(done.stdout), done.stderr

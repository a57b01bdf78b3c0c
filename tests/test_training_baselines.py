"""CNN baselines: export path always; torchvision models only when the optional extra is installed."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from extras import TORCH_MISSING, float32_sum_tolerance

torch = pytest.importorskip("torch", reason=TORCH_MISSING)

from courtloc.lab.eval import PaperOnnxModel  # noqa: E402
from courtloc.localizer.manifest import verify_weights  # noqa: E402
from courtloc.training.baselines import ARCHES, build_baseline, export_cnn  # noqa: E402
from courtloc.training.export import paper_manifest  # noqa: E402


def test_cnn_export_carries_a_manifest_and_runs(tmp_path: Path) -> None:
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(1, 4, 3, stride=2), torch.nn.ReLU(), torch.nn.AdaptiveAvgPool2d(1),
                              torch.nn.Flatten(), torch.nn.Linear(4, 2))
    manifest = paper_manifest("dense", {}, 32, 64, 16, "tiny-cnn", 1, "seed-gazebo", "seed-gazebo")
    path = export_cnn(net, 32, 64, tmp_path / "cnn.onnx", manifest)
    assert verify_weights(path).input.tensors[0].shape == [1, 1, 32, 64]
    dots = np.zeros((48, 64), np.uint8)
    dots[30:33, 10:20] = 1
    expected = net(torch.from_numpy(dots[16:].astype(np.float32))[None, None]).detach().numpy()[0]
    # onnxruntime's and torch's convolutions sum the 4 x 3 x 3 products and the pooled map in their own orders.
    got = PaperOnnxModel(path).predict_dots(dots)
    assert np.allclose(got, expected, rtol=0, atol=float32_sum_tolerance(32 * 64, float(np.abs(expected).max())))


@pytest.mark.parametrize("arch", ARCHES)
def test_baselines_take_one_channel(arch: str) -> None:
    pytest.importorskip("torchvision")
    model = build_baseline(arch).eval()
    with torch.no_grad():
        out = model(torch.zeros(1, 1, 280, 640))
    assert out.shape == (1, 2)


def _run(argv: list[str]) -> int:
    from courtloc.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    return int(exit_info.value.code or 0)


def test_frame_steps_stride_each_side_of_the_recording_split(tmp_path: Path) -> None:
    from courtloc.lab.datasets import Dataset
    from courtloc.training.toy_data import write_toy_dataset
    from courtloc.training.trainer import TrainConfig, _split

    data = write_toy_dataset(tmp_path / "toy", frames_per_recording=10)
    dataset = Dataset(data)
    cfg = TrainConfig(data=data, out=tmp_path / "run", train_recordings=["20240101"], val_recordings=["20240102"],
                      frame_step=3, val_frame_step=4)
    train_idx, val_idx = _split(dataset, cfg)
    full_train, full_val = dataset.indices_of(["20240101"]), dataset.indices_of(["20240102"])
    assert train_idx.tolist() == full_train[::3].tolist() and len(train_idx) == 4
    assert val_idx.tolist() == full_val[::4].tolist() and len(val_idx) == 3
    assert set(dataset.recordings[train_idx]) == {"20240101"} and set(dataset.recordings[val_idx]) == {"20240102"}


def test_downscale_is_refused_for_the_paper_network(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--downscale", "2"]) == 2
    assert "CNN baselines only" in capsys.readouterr().err  # a mistake is one line on stderr


def test_baseline_training_without_torchvision_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if importlib.util.find_spec("torchvision") is not None:
        pytest.skip("torchvision is installed")
    assert _run(["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--arch", "mobilenet_v2"]) == 2
    assert "torchvision" in capsys.readouterr().err


def test_downscaled_baseline_keeps_the_full_input_and_pools_by_max() -> None:
    pytest.importorskip("torchvision")
    model = build_baseline("mobilenet_v2", downscale=2).eval()
    assert isinstance(model[0], torch.nn.MaxPool2d)
    image = torch.zeros(1, 1, 280, 640)
    image[0, 0, 101, 301] = 1.0  # one lit pixel on an odd row/col: the max-pool keeps it, a mean would quarter it
    assert model[0](image).max() == 1.0


def test_train_baseline_end_to_end(tmp_path: Path) -> None:
    pytest.importorskip("torchvision")
    from courtloc.localizer.manifest import read_manifest
    from courtloc.training.toy_data import write_toy_dataset

    data = write_toy_dataset(tmp_path / "toy", frames_per_recording=16)
    run = tmp_path / "run"
    assert _run(["train", "--data", str(data), "--out", str(run), "--arch", "mobilenet_v2", "--crop-top", "16",
                 "--epochs", "1", "--frame-step", "2", "--downscale", "2", "--train-recordings", "20240101",
                 "--val-recordings", "20240102", "--no-progress"]) == 0
    summary = json.loads((run / "mobilenet_v2_history.json").read_text())
    assert summary["n_train"] == 8 and summary["val_recordings"] == ["20240102"]
    assert summary["config"]["downscale"] == 2 and len(summary["history"]) == 1
    onnx_file = run / "mobilenet_v2.onnx"
    manifest = read_manifest(onnx_file)
    assert manifest.input.kind == "dense_image" and manifest.input.tensors[0].shape == [1, 1, 32, 64]
    assert manifest.extra["architecture"].startswith("2x2 max-pool")
    metrics_file = tmp_path / "eval.json"
    assert _run(["eval", "--data", str(data), "--model", str(onnx_file), "--recordings", "20240102",
                 "--json", str(metrics_file), "--no-progress"]) == 0
    metrics = json.loads(metrics_file.read_text())
    assert metrics["n"] == 16  # the exported graph scores every held-out frame, like the training-side summary
    assert metrics["mse"] == pytest.approx(summary["metrics"]["val"]["mse"], rel=1e-4, abs=1e-6)

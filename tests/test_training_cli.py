"""`courtloc train / export / eval / explain / bench paper` end to end on a tiny synthetic set."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
from extras import TORCH_MISSING

torch = pytest.importorskip("torch", reason=TORCH_MISSING)

from courtloc.cli import main  # noqa: E402
from courtloc.training.toy_data import write_toy_dataset  # noqa: E402


def _run(argv: list[str]) -> int:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    return int(exit_info.value.code or 0)


def test_train_export_eval_explain(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = write_toy_dataset(tmp_path / "toy", frames_per_recording=16)
    run = tmp_path / "run"
    assert _run(["train", "--data", str(data), "--out", str(run), "--crop-top", "16", "--epochs", "2",
                 "--lr", "1e-3", "--seed", "3", "--train-recordings", "20240101",
                 "--val-recordings", "20240102", "--no-progress"]) == 0
    assert _run(["export", "onnx", str(run / "model.pt"), "--out", str(run / "onnx"), "--version", "5"]) == 0
    metrics_file = tmp_path / "eval.json"
    plots = tmp_path / "plots"
    capsys.readouterr()
    assert _run(["eval", "--data", str(data), "--model", str(run / "onnx" / "paper-mlp-sparse.onnx"),
                 "--recordings", "20240102", "--json", str(metrics_file), "--plots", str(plots),
                 "--no-progress"]) == 0
    metrics = json.loads(metrics_file.read_text())
    assert set(metrics) == {"n", "mse", "mae_x", "mae_y", "mean_err_m", "median_err_m", "p95_err_m",
                            "valid_fraction", "valid_mean_err_m", "valid_p95_err_m", "valid_wrong"}
    assert metrics["n"] == 16
    summary = json.loads((run / "history.json").read_text())
    assert metrics["mse"] == pytest.approx(summary["metrics"]["val"]["mse"], abs=1e-5)
    lines = (plots / "predictions.csv").read_text().splitlines()
    assert len(lines) == 17 and lines[0].startswith("image_filename,")
    if importlib.util.find_spec("matplotlib") is not None:  # plots are optional; the numbers are not
        assert {p.name for p in plots.glob("*.png")} == {"truth_vs_prediction.png", "error_cdf.png",
                                                           "error_by_region.png"}
    image = sorted((data / "images").iterdir())[0]
    assert _run(["explain", "--model", str(run / "model.pt"), str(image), "--out", str(tmp_path / "ig"),
                 "--steps", "8"]) == 0
    import cv2

    saliency = cv2.imread(str(tmp_path / "ig" / f"{image.stem}_ig.png"))
    assert saliency is not None and saliency.shape == (48, 64, 3)


def test_integrated_gradients_sit_on_the_dots_and_are_complete() -> None:
    from courtloc.training.explain import integrated_gradients
    from courtloc.training.paper_model import DensePaperNet, SparsePaperNet

    torch.manual_seed(0)
    model = DensePaperNet.from_weights(SparsePaperNet(12 * 16).numpy_weights())
    image = np.zeros((1, 12, 16), np.float32)
    image[0, 3:5, 4:7] = 1.0
    attributions, pred, gap = integrated_gradients(model, image, steps=64)
    assert attributions.shape == (2, 12, 16)
    assert np.count_nonzero(attributions[:, image[0] == 0]) == 0  # black baseline: nothing off the dots
    assert np.count_nonzero(attributions[:, image[0] == 1]) > 0
    assert np.all(np.abs(gap) < 1e-3)  # sum of attributions == f(x) - f(baseline)


def test_bench_paper_compares_dense_and_sparse(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from courtloc.training.export import export_paper
    from courtloc.training.trainer import TrainConfig, train

    data = write_toy_dataset(tmp_path / "toy", frames_per_recording=6)
    train(TrainConfig(data=data, out=tmp_path / "run", crop_top=16, epochs=1, progress=False))
    paths = export_paper(tmp_path / "run" / "model.pt", tmp_path / "onnx")
    out = tmp_path / "bench.json"
    capsys.readouterr()
    assert _run(["bench", "paper", "--model", f"dense={paths['dense']}", "--model", f"sparse={paths['sparse']}",
                 "--data", str(data), "--frames", "5", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["name"] for r in rows] == ["dense", "sparse"]
    assert rows[0]["mse"] == pytest.approx(rows[1]["mse"], abs=1e-6)  # same function, two graphs
    assert all(r["peak_rss_mb"] > 10 and r["n"] == 5 for r in rows)
    assert rows[0]["latency_ratio_vs_first"] == 1.0

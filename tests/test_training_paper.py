"""The paper network's training path on a tiny synthetic set: same code as the full run, smaller input."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from extras import TORCH_MISSING, float32_sum_tolerance

torch = pytest.importorskip("torch", reason=TORCH_MISSING)

from courtloc.lab.datasets import load_dataset  # noqa: E402
from courtloc.lab.eval import PaperOnnxModel, evaluate, open_model  # noqa: E402
from courtloc.localizer.manifest import read_manifest, verify_weights  # noqa: E402
from courtloc.training.export import export_paper  # noqa: E402
from courtloc.training.lazy_adam import LazyAdamRows, RowBatch  # noqa: E402
from courtloc.training.paper_model import HIDDEN, DensePaperNet, SparsePaperNet  # noqa: E402
from courtloc.training.toy_data import write_toy_dataset  # noqa: E402
from courtloc.training.trainer import TrainConfig, train  # noqa: E402

CROP = 16  # toy frames are 48 x 64: a 32 x 64 input (2048 pixels) instead of 280 x 640


@pytest.fixture(scope="module")
def toy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_toy_dataset(tmp_path_factory.mktemp("toy"), frames_per_recording=24, crop_top=CROP)


@pytest.fixture(scope="module")
def trained(toy: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("run")
    summary = train(TrainConfig(data=toy, out=out, crop_top=CROP, epochs=4, lr=1e-3, progress=False,
                                train_recordings=["20240101"], val_recordings=["20240102"]))
    return out, summary


def test_training_learns_and_writes_its_files(trained: tuple[Path, dict]) -> None:
    out, summary = trained
    history = summary["history"]
    assert [h["epoch"] for h in history] == [1, 2, 3, 4]
    assert history[-1]["train_loss"] < history[0]["train_loss"]
    assert summary["input_shape"] == [32, 64]
    assert summary["train_recordings"] == ["20240101"] and summary["val_recordings"] == ["20240102"]
    assert summary["metrics"]["train"]["n"] == 24 and summary["metrics"]["val"]["n"] == 24
    for name in ("last.pt", "model.pt", "history.json"):
        assert (out / name).is_file()
    pytest.importorskip("matplotlib")
    assert (out / "loss_curve.png").stat().st_size > 1000


def test_export_reload_and_evaluate(trained: tuple[Path, dict], toy: Path) -> None:
    out, summary = trained
    paths = export_paper(out / "model.pt", out / "onnx")
    dataset = load_dataset(toy)
    val = dataset.indices_of(["20240102"])
    dense, sparse = PaperOnnxModel(paths["dense"]), PaperOnnxModel(paths["sparse"])
    for i in range(len(dataset)):
        dots = dataset.dot_image(i)
        assert np.allclose(dense.predict_dots(dots), sparse.predict_dots(dots), atol=1e-4, rtol=0)
    # the exported graphs reproduce the trainer's own validation numbers
    result = evaluate(open_model(paths["sparse"]), dataset, val)
    assert result.metrics.n == 24
    assert result.metrics.mean_err_m == pytest.approx(summary["metrics"]["val"]["mean_err_m"], abs=1e-5)
    assert result.metrics.mse == pytest.approx(summary["metrics"]["val"]["mse"], abs=1e-5)
    manifest = verify_weights(paths["dense"])
    assert manifest.input.kind == "dense_image" and manifest.input.tensors[0].shape == [1, 32, 64]
    sparse_manifest = read_manifest(paths["sparse"])
    assert sparse_manifest.input.kind == "sparse_hits"
    assert [t.name for t in sparse_manifest.input.tensors] == ["indices", "values"]
    assert sparse_manifest.preprocessing.crop_top == CROP
    assert sparse_manifest.training_data.fingerprint == dataset.fingerprint(dataset.indices_of(["20240101"]))
    assert sparse_manifest.metrics["val"]["mean_err_m"] == pytest.approx(summary["metrics"]["val"]["mean_err_m"])


def test_sparse_graph_accepts_an_empty_image(trained: tuple[Path, dict]) -> None:
    out, _ = trained
    paths = export_paper(out / "model.pt", out / "onnx_empty", kinds=("dense", "sparse"))
    empty = np.zeros((48, 64), np.uint8)
    dense = PaperOnnxModel(paths["dense"]).predict_dots(empty)
    sparse = PaperOnnxModel(paths["sparse"]).predict_dots(empty)
    terms = max(48 * 64, *HIDDEN)  # the dense first layer sums every pixel (zeros here), then the hidden layers
    assert np.allclose(dense, sparse, rtol=0, atol=float32_sum_tolerance(terms, float(np.abs(dense).max())))


def test_resume_continues_exactly(toy: Path, tmp_path: Path) -> None:
    common = dict(data=toy, crop_top=CROP, lr=1e-3, progress=False, seed=7)
    train(TrainConfig(out=tmp_path / "a", epochs=3, **common))
    train(TrainConfig(out=tmp_path / "b", epochs=2, **common))
    resumed = train(TrainConfig(out=tmp_path / "b", epochs=3, resume=True, **common))
    assert [h["epoch"] for h in resumed["history"]] == [1, 2, 3]
    a = torch.load(tmp_path / "a" / "model.pt", weights_only=False)["weights"]
    b = torch.load(tmp_path / "b" / "model.pt", weights_only=False)["weights"]
    for name in a:
        assert np.allclose(a[name], b[name], atol=1e-6), name


def test_sparse_first_layer_is_the_dense_linear() -> None:
    torch.manual_seed(0)
    n_pixels = 300
    sparse_net = SparsePaperNet(n_pixels)
    dense_net = DensePaperNet.from_weights(sparse_net.numpy_weights())
    rng = np.random.default_rng(1)
    images = (rng.random((3, n_pixels)) < 0.05).astype(np.float32) * rng.random((3, n_pixels)).astype(np.float32)
    indices = [np.flatnonzero(img) for img in images]
    values = [img[idx] for img, idx in zip(images, indices)]
    # forward, through the training path (RowBatch) and through nn.Linear
    rows = RowBatch(indices, values)
    table = sparse_net.first.weight.data
    first = (rows.matrix.T @ table.index_select(0, rows.rows)).requires_grad_()
    out_sparse = sparse_net.tail(first + sparse_net.first_bias)
    x = torch.from_numpy(images).requires_grad_()
    out_dense = dense_net(x)
    # The longest float32 sums are the hidden layers' (or the dense first layer's n_pixels terms).
    terms = max(n_pixels, *HIDDEN)
    assert torch.allclose(out_sparse, out_dense, rtol=0,
                          atol=float32_sum_tolerance(terms, float(out_dense.abs().max())))
    # backward: the gathered-row gradient equals the dense weight gradient's columns
    out_sparse.sum().backward()
    out_dense.sum().backward()
    grad_rows = rows.matrix @ first.grad
    dense_grad = dense_net.net[1].weight.grad  # [1024, n_pixels]
    assert torch.allclose(grad_rows, dense_grad.T[rows.rows], rtol=0,
                          atol=float32_sum_tolerance(terms, float(dense_grad.abs().max())))
    untouched = torch.ones(n_pixels, dtype=torch.bool)
    untouched[rows.rows] = False
    assert torch.count_nonzero(dense_grad.T[untouched]) == 0


def test_lazy_adam_matches_adam_on_touched_rows() -> None:
    torch.manual_seed(0)
    table = torch.randn(50, 8)
    reference = torch.nn.Parameter(table.clone())
    lazy = LazyAdamRows(table, lr=1e-2)
    adam = torch.optim.Adam([reference], lr=1e-2)
    rows = torch.tensor([3, 7, 20, 49])
    for _ in range(3):  # same rows every step: lazy and dense Adam must agree everywhere
        grad_rows = torch.randn(4, 8)
        lazy.step(rows, table.index_select(0, rows), grad_rows)
        reference.grad = torch.zeros(50, 8).index_copy_(0, rows, grad_rows)
        adam.step()
    # Each step rounds the weight once and its ~10 elementwise update operations once each (of size lr):
    # two implementations may order them differently (torch picks kernels per CPU).
    steps, ops, lr = 3, 10, 1e-2
    tol = steps * float32_sum_tolerance(1, float(table.abs().max())) + steps * ops * float32_sum_tolerance(1, 1.0) * lr
    assert torch.allclose(table, reference.detach(), rtol=0, atol=tol)
    # a row never touched keeps its weight
    assert torch.equal(table[0], reference.detach()[0])


def test_checkpoint_exports_like_the_final_model(trained: tuple[Path, dict], toy: Path) -> None:
    out, _ = trained
    final = export_paper(out / "model.pt", out / "final", kinds=("sparse",))["sparse"]
    from_checkpoint = export_paper(out / "last.pt", out / "ckpt", kinds=("sparse",))["sparse"]
    dots = load_dataset(toy).dot_image(5)
    assert np.allclose(PaperOnnxModel(final).predict_dots(dots), PaperOnnxModel(from_checkpoint).predict_dots(dots),
                       atol=1e-6)
    assert read_manifest(from_checkpoint).input.tensors[0].shape == ["K"]

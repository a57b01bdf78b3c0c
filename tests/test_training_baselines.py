"""CNN baselines: export path always; torchvision models only when the optional extra is installed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from courtloc.localizer.eval import PaperOnnxModel  # noqa: E402
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
    assert np.allclose(PaperOnnxModel(path).predict_dots(dots), expected, atol=1e-5)


@pytest.mark.parametrize("arch", ARCHES)
def test_baselines_take_one_channel(arch: str) -> None:
    pytest.importorskip("torchvision")
    model = build_baseline(arch).eval()
    with torch.no_grad():
        out = model(torch.zeros(1, 1, 280, 640))
    assert out.shape == (1, 2)

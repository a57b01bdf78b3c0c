"""The paper's network (Flatten -> 179200 -> 1024 -> 256 -> 64 -> 2, ReLU between), in two exact forms.

`SparsePaperNet` trains on a CPU: its first layer is an `EmbeddingBag(n_pixels, 1024, mode="sum")`
whose row p is column p of the paper's Linear weight, so for a flattened input v
    sum_p W[:, p] * v[p] over the non-zero p  ==  W @ v
exactly (up to float summation order). `DensePaperNet` is the paper's literal form (nn.Linear); it is
what Integrated Gradients runs through and what the dense ONNX export mirrors.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

HIDDEN = (1024, 256, 64)  # the paper's layer widths
OUTPUTS = 2  # x, y in metres


def _tail() -> nn.Sequential:
    layers: list[nn.Module] = []
    for width_in, width_out in zip(HIDDEN, HIDDEN[1:] + (OUTPUTS,)):
        layers += [nn.ReLU(), nn.Linear(width_in, width_out)]
    return nn.Sequential(*layers)


class SparsePaperNet(nn.Module):
    def __init__(self, n_pixels: int) -> None:
        super().__init__()
        self.n_pixels = n_pixels
        self.first = nn.EmbeddingBag(n_pixels, HIDDEN[0], mode="sum", sparse=True)
        self.first_bias = nn.Parameter(torch.empty(HIDDEN[0]))
        # nn.Linear's default initialisation for a fan-in of n_pixels, so training starts where the paper's does.
        bound = 1.0 / math.sqrt(n_pixels)
        nn.init.uniform_(self.first.weight, -bound, bound)
        nn.init.uniform_(self.first_bias, -bound, bound)
        self.tail = _tail()

    def forward(self, indices: torch.Tensor, values: torch.Tensor, offsets: torch.Tensor) -> torch.Tensor:
        """indices/values: the concatenated non-zero pixels of a batch; offsets: where each sample starts."""
        hidden = self.first(indices, offsets, per_sample_weights=values) + self.first_bias
        return self.tail(hidden)

    def dense_parameters(self) -> list[nn.Parameter]:
        return [self.first_bias, *self.tail.parameters()]

    def numpy_weights(self) -> dict[str, np.ndarray]:
        """Weights in the paper's layout: w1 [1024, n_pixels], b1, w2 [256, 1024], ..., b4."""
        out = {"w1": self.first.weight.detach().numpy().T, "b1": self.first_bias.detach().numpy()}
        linears = [m for m in self.tail if isinstance(m, nn.Linear)]
        for k, layer in enumerate(linears, start=2):
            out[f"w{k}"] = layer.weight.detach().numpy()
            out[f"b{k}"] = layer.bias.detach().numpy()
        return out


class DensePaperNet(nn.Module):
    def __init__(self, n_pixels: int) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Flatten(), nn.Linear(n_pixels, HIDDEN[0]), *_tail())

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        return self.net(image)

    @classmethod
    def from_weights(cls, weights: dict[str, np.ndarray]) -> "DensePaperNet":
        model = cls(weights["w1"].shape[1])
        linears = [m for m in model.net if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for k, layer in enumerate(linears, start=1):
                layer.weight.copy_(torch.from_numpy(np.ascontiguousarray(weights[f"w{k}"])))
                layer.bias.copy_(torch.from_numpy(weights[f"b{k}"]))
        return model.eval()

"""The paper network as ONNX, built from numpy weights (no torch needed), in two exact forms.

- dense:  input `image` float32 [1, H, W] -> Reshape -> Gemm(w1) -> ReLU -> ... -> `xy` float32 [1, 2]
          (the paper's graph; its first weight is 1024 x 179200 floats = 734 MB).
- sparse: inputs `indices` int64 [K] (row-major flat pixel index into the H x W crop) and `values`
          float32 [K] -> Gather(w1^T rows) -> MatMul(values[1, K]) -> + b1 -> ReLU -> ... -> `xy` [1, 2].
          Same weights, so it is the same function of the image; it only touches the K lit pixels.
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17
IR_VERSION = 8  # readable by the onnxruntime versions on the Jetson (JetPack 6) as well as here
DENSE_INPUT = "image"
SPARSE_INDICES = "indices"
SPARSE_VALUES = "values"
OUTPUT = "xy"


def _tail_nodes(first: str) -> tuple[list[onnx.NodeProto], list[str]]:
    """ReLU -> Gemm(w2,b2) -> ReLU -> Gemm(w3,b3) -> ReLU -> Gemm(w4,b4) -> OUTPUT."""
    nodes, names = [], []
    current = first
    for k in (2, 3, 4):
        relu = f"relu{k - 1}"
        out = OUTPUT if k == 4 else f"h{k}"
        nodes += [helper.make_node("Relu", [current], [relu]),
                  helper.make_node("Gemm", [relu, f"w{k}", f"b{k}"], [out], transB=1)]
        names += [f"w{k}", f"b{k}"]
        current = out
    return nodes, names


def _model(graph: onnx.GraphProto) -> onnx.ModelProto:
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], ir_version=IR_VERSION,
                              producer_name="courtloc.training")
    return model


def _initializers(weights: dict[str, np.ndarray], names: list[str]) -> list[onnx.TensorProto]:
    return [numpy_helper.from_array(np.ascontiguousarray(weights[n], dtype=np.float32), n) for n in names]


def build_dense(weights: dict[str, np.ndarray], height: int, width: int) -> onnx.ModelProto:
    n_pixels = height * width
    if weights["w1"].shape != (1024, n_pixels):
        raise ValueError(f"w1 has shape {weights['w1'].shape}, expected (1024, {n_pixels})")
    tail, tail_names = _tail_nodes("h1")
    nodes = [helper.make_node("Reshape", [DENSE_INPUT, "flat_shape"], ["flat"]),
             helper.make_node("Gemm", ["flat", "w1", "b1"], ["h1"], transB=1), *tail]
    inits = [numpy_helper.from_array(np.array([1, n_pixels], np.int64), "flat_shape"),
             *_initializers(weights, ["w1", "b1", *tail_names])]
    graph = helper.make_graph(
        nodes, "paper_dense",
        [helper.make_tensor_value_info(DENSE_INPUT, TensorProto.FLOAT, [1, height, width])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, [1, 2])], inits)
    return _model(graph)


def build_sparse(weights: dict[str, np.ndarray]) -> onnx.ModelProto:
    w1t = np.ascontiguousarray(weights["w1"].T)  # row p = the weights of pixel p
    tail, tail_names = _tail_nodes("h1")
    nodes = [helper.make_node("Gather", ["w1t", SPARSE_INDICES], ["rows"], axis=0),
             helper.make_node("Unsqueeze", [SPARSE_VALUES, "axis0"], ["values_row"]),
             helper.make_node("MatMul", ["values_row", "rows"], ["h1_nobias"]),
             helper.make_node("Add", ["h1_nobias", "b1"], ["h1"]), *tail]
    inits = [numpy_helper.from_array(w1t.astype(np.float32, copy=False), "w1t"),
             numpy_helper.from_array(np.array([0], np.int64), "axis0"),
             *_initializers(weights, ["b1", *tail_names])]
    graph = helper.make_graph(
        nodes, "paper_sparse",
        [helper.make_tensor_value_info(SPARSE_INDICES, TensorProto.INT64, ["K"]),
         helper.make_tensor_value_info(SPARSE_VALUES, TensorProto.FLOAT, ["K"])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, [1, 2])], inits)
    return _model(graph)

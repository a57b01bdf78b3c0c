"""The ONNX part of the geometric localizer: scan hits -> robot-frame floor points.

The graph carries the camera as a per-pixel table (H * W x 2 floor points, built by
projection.build_floor_table, distortion and the scan's edge offset included), so the package's ONNX
file alone turns a frame's hits into floor geometry, and a recalibrated camera is a new table, not new
code. Pixels outside the image or seeing no floor within range give NaN (dropped by the fit).

    hits int16 [K, 4] (row, col, ray, d)  ->  floor_xy float32 [K, 2] (metres, robot frame)
"""
from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

INPUT = "hits"
OUTPUT = "floor_xy"
OPSET = 17


def build_graph(table: np.ndarray, height: int, width: int):  # -> onnx.ModelProto
    if table.shape != (height * width, 2):
        raise ValueError(f"floor table shape {table.shape} does not match a {width}x{height} frame")
    inits = [
        numpy_helper.from_array(np.ascontiguousarray(table, np.float32), "floor_table"),
        numpy_helper.from_array(np.array([0], np.int64), "i0"),
        numpy_helper.from_array(np.array([1], np.int64), "i1"),
        numpy_helper.from_array(np.array(0, np.int64), "zero"),
        numpy_helper.from_array(np.array(height - 1, np.int64), "max_row"),
        numpy_helper.from_array(np.array(width - 1, np.int64), "max_col"),
        numpy_helper.from_array(np.array(width, np.int64), "width"),
        numpy_helper.from_array(np.array([np.nan], np.float32), "nan"),
    ]
    nodes = [
        helper.make_node("Cast", [INPUT], ["hits64"], to=TensorProto.INT64),
        helper.make_node("Gather", ["hits64", "i0"], ["row_k1"], axis=1),
        helper.make_node("Gather", ["hits64", "i1"], ["col_k1"], axis=1),
        helper.make_node("Squeeze", ["row_k1", "i1"], ["row"]),
        helper.make_node("Squeeze", ["col_k1", "i1"], ["col"]),
        # Clamp into the image for a safe gather; the clamped ones are masked to NaN below.
        helper.make_node("Max", ["row", "zero"], ["row_lo"]),
        helper.make_node("Min", ["row_lo", "max_row"], ["row_c"]),
        helper.make_node("Max", ["col", "zero"], ["col_lo"]),
        helper.make_node("Min", ["col_lo", "max_col"], ["col_c"]),
        helper.make_node("Equal", ["row", "row_c"], ["row_ok"]),
        helper.make_node("Equal", ["col", "col_c"], ["col_ok"]),
        helper.make_node("And", ["row_ok", "col_ok"], ["ok"]),
        helper.make_node("Unsqueeze", ["ok", "i1"], ["ok_k1"]),
        helper.make_node("Mul", ["row_c", "width"], ["row_base"]),
        helper.make_node("Add", ["row_base", "col_c"], ["flat"]),
        helper.make_node("Gather", ["floor_table", "flat"], ["table_xy"], axis=0),
        helper.make_node("Where", ["ok_k1", "table_xy", "nan"], [OUTPUT]),
    ]
    graph = helper.make_graph(
        nodes, "courtloc_hits_to_floor",
        [helper.make_tensor_value_info(INPUT, TensorProto.INT16, ["K", 4])],
        [helper.make_tensor_value_info(OUTPUT, TensorProto.FLOAT, ["K", 2])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="courtloc.localizer")
    model.ir_version = 8  # readable by the onnxruntime versions JetPack ships
    onnx.checker.check_model(model)
    return model

"""A model file read once: its bytes, its parsed graph and its manifest, for every check and the session.

Loading a pushed model used to parse model.onnx once per question (manifest, weights, graph signature,
floor table, session). Everything that asks now asks this one object.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

from courtloc.localizer.manifest import Manifest, ManifestError, manifest_from_model, weights_sha256


@dataclass(frozen=True)
class ModelFile:
    path: Path
    data: bytes  # the serialized graph: onnxruntime builds its session from these bytes
    proto: onnx.ModelProto
    manifest: Manifest

    @classmethod
    def read(cls, path: Path | str) -> "ModelFile":
        """Read and parse `path`; ManifestError when it is missing, not ONNX or has no usable manifest."""
        path = Path(path)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise ManifestError(f"model file not readable: {path}: {exc.strerror or exc}") from None
        try:
            proto = onnx.load_from_string(data)
        except Exception as exc:  # protobuf's DecodeError and friends on a truncated or foreign file
            raise ManifestError(f"not a readable ONNX model: {type(exc).__name__}: {exc}") from None
        return cls(path=path, data=data, proto=proto, manifest=manifest_from_model(proto))

    def verify_weights(self) -> None:
        """The weights hash to the manifest's weights_sha256; ManifestError when they do not."""
        actual = weights_sha256(self.proto)
        if self.manifest.weights_sha256 != actual:
            raise ManifestError(f"{self.path.name}: weights sha256 {actual[:12]}... does not match the "
                                f"manifest's {self.manifest.weights_sha256[:12] or '(empty)'}...")

    def initializer(self, name: str) -> np.ndarray | None:
        """The named weight tensor as numpy, or None when the graph has none of that name."""
        for init in self.proto.graph.initializer:
            if init.name == name:
                return numpy_helper.to_array(init)
        return None

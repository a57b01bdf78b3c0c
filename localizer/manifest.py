"""The model manifest: what a model expects and what it gives, stored inside its ONNX file.

The manifest is JSON in the ONNX model's `metadata_props` under the key `courtloc.manifest`, so the
file alone says how to feed it (input kind, tensor names/shapes, preprocessing), what comes out
(names, units), what court and camera it assumes, what it was trained on and how well it did.

`weights_sha256` is defined as: sha256 over every graph initializer, in graph order, of
    name (utf-8) + b"\\0" + dtype name (numpy, e.g. "float32") + b"\\0" + shape ("179200x1024") + b"\\0"
    + the tensor's little-endian C-order bytes (numpy_helper.to_array(...).tobytes()).
It ignores metadata (so writing the manifest does not change it) and how the tensors are stored
(raw_data, typed fields or external data). `verify_weights` recomputes and compares it.
"""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Literal, Optional, Union

import onnx
from onnx import numpy_helper
from pydantic import BaseModel, ConfigDict, Field

from courtloc.scan.config import DEFAULT_HSV_RANGES, ScanConfig

MANIFEST_KEY = "courtloc.manifest"
SCHEMA = "courtloc.manifest/1"

# The one rule for every name the model store and a package use as a path component: model names,
# pushed file names, package parts. It starts with a letter or digit, so '.', '..' and the store's own
# dot-files ('.active.json', '.incoming', '.files.json') can never be named; 128 characters keep it far
# below any filesystem's name limit.
PLAIN_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$"
PLAIN_NAME_RULE = "a plain name: a letter or digit, then letters, digits, '_', '.', '-'; at most 128 characters"


def is_plain_name(name: str) -> bool:
    return re.fullmatch(PLAIN_NAME_PATTERN, name) is not None


# 'dense_image': the paper's crop as float32 [1, H, W]; 'sparse_hits': indices + values of its non-zero
# pixels; 'scan_hits': the radial scan's int16 [K, 4] (row, col, ray, d) hits (geometric localizer).
# Extend this Literal when a new kind of model input appears.
InputKind = Literal["dense_image", "sparse_hits", "scan_hits"]
PAPER_KINDS: tuple[InputKind, ...] = ("dense_image", "sparse_hits")  # the paper network's two graphs
MODEL_FILE = "model.onnx"  # the graph inside a model folder (a package or a store version)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class TensorSpec(_Strict):
    name: str
    dtype: str  # numpy dtype name: float32, int64 ...
    shape: list[Union[int, str]]  # str for a symbolic dimension, e.g. "K" hits


class InputSpec(_Strict):
    kind: InputKind
    tensors: list[TensorSpec] = Field(min_length=1)
    description: str = ""


class HsvRange(_Strict):
    lower: tuple[int, int, int]
    upper: tuple[int, int, int]


class PreprocessSpec(_Strict):
    """The preprocessing the model was trained behind; a mismatch at load time is a reason to refuse it."""

    frame_width: int = 640
    frame_height: int = 480
    hsv_ranges: list[HsvRange] = Field(default_factory=list)
    scan_step_deg: float = 2.0
    scan_origin: tuple[float, float] = (320.0, 480.0)  # (col, row): bottom-centre pixel
    crop_top: int = 200
    dot_radius: int = 2
    dot_threshold: int = 128  # applied to stored (JPEG) dot images before use
    scale: str = "0/1 dot image as float32 in [0, 1]"


def runtime_preprocessing(width: int = 640, height: int = 480, crop_top: int = 200) -> PreprocessSpec:
    """The preprocess stage's own defaults for a width x height frame, so that a manifest states what the
    robot will do (the scan origin is the last row's centre: where the seed images' rays start, see
    docs/preprocess.md)."""

    scan = ScanConfig()
    return PreprocessSpec(frame_width=width, frame_height=height, crop_top=crop_top,
                          hsv_ranges=[HsvRange(lower=r.lower, upper=r.upper) for r in DEFAULT_HSV_RANGES],
                          scan_step_deg=scan.angle_step_deg, scan_origin=scan.origin_for(height, width))


class OutputSpec(_Strict):
    name: str
    components: list[str]
    units: list[str]


class TrainingData(_Strict):
    fingerprint: str  # courtloc.lab.datasets.Dataset.fingerprint over the training frames
    recordings: list[str] = Field(default_factory=list)
    n_frames: int = 0
    description: str = ""


class GoldenSpec(_Strict):
    """Golden inputs shipped beside the model (made when it was built, at known poses) and the accuracy the
    model states on them: a robot refuses a candidate whose golden error exceeds these numbers."""

    file: str = Field(default="golden.npz", pattern=PLAIN_NAME_PATTERN)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    n_frames: int = Field(ge=1)
    max_position_error_m: float = Field(gt=0, description="stated accuracy: the largest position error on a golden "
                                        "frame")
    max_yaw_error_deg: Optional[float] = Field(default=None, gt=0, description="the same for yaw; None: no yaw output")


class Manifest(_Strict):
    schema_: str = Field(default=SCHEMA, alias="schema")
    name: str
    version: int = Field(ge=0)
    input: InputSpec
    preprocessing: PreprocessSpec = Field(default_factory=PreprocessSpec)
    court: str
    camera: str
    outputs: list[OutputSpec] = Field(min_length=1)
    training_data: Optional[TrainingData] = None
    metrics: dict[str, dict[str, float]] = Field(default_factory=dict)  # split name -> PoseMetrics dict
    weights_sha256: str = ""
    golden: Optional[GoldenSpec] = None
    extra: dict[str, Union[str, float, int, bool]] = Field(default_factory=dict)

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    def to_json(self) -> str:
        return self.model_dump_json(by_alias=True)


class ManifestError(ValueError):
    """A model file without a readable manifest, or whose weights do not match it."""


def weights_sha256(model: "onnx.ModelProto") -> str:  # noqa: F821 - onnx imported lazily
    digest = hashlib.sha256()
    for tensor in model.graph.initializer:
        array = numpy_helper.to_array(tensor)
        little = array.astype(array.dtype.newbyteorder("<"), copy=False)
        shape = "x".join(str(d) for d in array.shape)
        digest.update(f"{tensor.name}\0{array.dtype.name}\0{shape}\0".encode())
        digest.update(little.tobytes(order="C"))
    return digest.hexdigest()


def _load(onnx_path: Path, with_weights: bool) -> "onnx.ModelProto":  # noqa: F821
    if not Path(onnx_path).is_file():
        raise ManifestError(f"model file not found: {onnx_path}")
    return onnx.load(str(onnx_path), load_external_data=with_weights)


def manifest_from_model(model: "onnx.ModelProto") -> Manifest:  # noqa: F821
    for prop in model.metadata_props:
        if prop.key == MANIFEST_KEY:
            try:
                return Manifest.model_validate(json.loads(prop.value))
            except (ValueError, TypeError) as exc:
                raise ManifestError(f"bad manifest: {exc}") from exc
    raise ManifestError(f"no '{MANIFEST_KEY}' entry in the model's metadata_props")


def read_manifest(onnx_path: Path) -> Manifest:
    """The manifest of an ONNX file (weights are not checked; see verify_weights)."""
    return manifest_from_model(_load(onnx_path, with_weights=False))


def attach_manifest(model: "onnx.ModelProto", manifest: Manifest) -> Manifest:  # noqa: F821
    """Set the manifest (with weights_sha256 computed from `model`) into the in-memory model."""
    final = manifest.model_copy(update={"weights_sha256": weights_sha256(model)})
    kept = [p for p in model.metadata_props if p.key != MANIFEST_KEY]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    entry = model.metadata_props.add()
    entry.key, entry.value = MANIFEST_KEY, final.to_json()
    return final


def write_manifest(onnx_path: Path, manifest: Manifest) -> Manifest:
    """Store `manifest` in the file (replacing any old one); returns it with weights_sha256 filled in."""

    model = _load(onnx_path, with_weights=True)
    final = attach_manifest(model, manifest)
    onnx.save(model, str(onnx_path))
    return final


def verify_weights(onnx_path: Path) -> Manifest:
    """Read the manifest and check the file's weights against its weights_sha256; raise on mismatch."""
    model = _load(onnx_path, with_weights=True)
    manifest = manifest_from_model(model)
    actual = weights_sha256(model)
    if manifest.weights_sha256 != actual:
        raise ManifestError(f"{onnx_path}: weights sha256 {actual[:12]}... does not match the manifest's "
                            f"{manifest.weights_sha256[:12] or '(empty)'}...")
    return manifest


def sha256_of(path: Path, block: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        while chunk := handle.read(block):
            digest.update(chunk)
    return digest.hexdigest()


def package_part(folder: Path, name: object, sha256: object, what: str) -> Path:
    """The file `name` of the package in `folder`, checked against the `sha256` its manifest states.

    It must be a plain name that resolves (symlinks followed) to a regular file directly inside the
    folder. Missing, outside, not a file or different content all raise the same text, so an answer
    never tells what exists where.
    """
    refused = ManifestError(f"package part {what!r} is missing or is not the file its manifest names")
    if not isinstance(name, str) or not is_plain_name(name) or not isinstance(sha256, str):
        raise refused
    try:
        path = (Path(folder) / name).resolve(strict=True)
        if path.parent != Path(folder).resolve(strict=True) or not path.is_file() or sha256_of(path) != sha256:
            raise refused
    except OSError:
        raise refused from None
    return path

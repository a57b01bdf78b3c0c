"""A geometric-localizer package: one folder that is everything the robot needs to localise.

    model.onnx       hits -> floor points (the camera as a per-pixel table), manifest in metadata_props
    court.json       the court model (courtloc.sim.court format): the distance field is built from it at load
    camera.json      the camera model (courtloc.sim.camera format): the fit's per-hit error model
    localizer.json   LocalizerConfig (robust fit, quality thresholds, search, symmetry mode)
    README.md        what it is and how well it did (evaluation report)

The manifest names the three JSON files (extra.court_file ...) and carries their sha256, so a package
whose parts do not belong together is refused at load.
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.manifest import (InputSpec, Manifest, ManifestError, OutputSpec, TensorSpec, TrainingData,
                                         attach_manifest, read_manifest, runtime_preprocessing, verify_weights)
from courtloc.localizer.onnx_graph import INPUT, OUTPUT, build_graph
from courtloc.localizer.projection import build_floor_table
from courtloc.sim.camera import CameraModel, load_camera
from courtloc.sim.court import Court, load_court

log = logging.getLogger(__name__)

MODEL_FILE = "model.onnx"
COURT_FILE = "court.json"
CAMERA_FILE = "camera.json"
CONFIG_FILE = "localizer.json"
KIND = "geometric"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def build_package(out_dir: Path, court: Court, camera: CameraModel, config: LocalizerConfig | None = None,
                  name: str = "courtloc-geometric", version: int = 1,
                  metrics: dict[str, dict[str, float]] | None = None,
                  training_data: TrainingData | None = None) -> Manifest:
    """Write a package folder; returns the manifest stored in its model.onnx."""
    import onnx

    config = config or LocalizerConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / COURT_FILE).write_text(court.model_dump_json(indent=1))
    (out_dir / CAMERA_FILE).write_text(camera.model_dump_json(indent=1))
    (out_dir / CONFIG_FILE).write_text(config.model_dump_json(indent=1))
    table = build_floor_table(camera, config.edge_offset_px, config.max_range_m)
    model = build_graph(table, camera.height, camera.width)
    manifest = Manifest(
        name=name, version=version,
        input=InputSpec(kind="scan_hits", description="radial-scan hits of one frame, full-frame pixel "
                        "coordinates (row, col, ray, d), as on the preprocess stage's Edges message",
                        tensors=[TensorSpec(name=INPUT, dtype="int16", shape=["K", 4])]),
        preprocessing=runtime_preprocessing(camera.width, camera.height),
        court=court.name, camera=camera.name,
        outputs=[OutputSpec(name=OUTPUT, components=["x_robot", "y_robot"], units=["m", "m"])],
        training_data=training_data, metrics=metrics or {},
        extra={
            "localizer": KIND,
            "pose_outputs": "x m, y m, yaw rad (court frame), quality 0..1, valid",
            "court_file": COURT_FILE, "court_sha256": _sha(out_dir / COURT_FILE),
            "camera_file": CAMERA_FILE, "camera_sha256": _sha(out_dir / CAMERA_FILE),
            "config_file": CONFIG_FILE, "config_sha256": _sha(out_dir / CONFIG_FILE),
            "edge_offset_px": config.edge_offset_px,
            "symmetry": config.symmetry, "half": config.half,
        },
    )
    final = attach_manifest(model, manifest)
    onnx.save(model, str(out_dir / MODEL_FILE))
    log.info("wrote localizer package %s (%s / %s)", out_dir, court.name, camera.name)
    return final


@dataclass(frozen=True)
class Package:
    folder: Path
    manifest: Manifest
    court: Court
    camera: CameraModel
    config: LocalizerConfig

    @property
    def model_path(self) -> Path:
        return self.folder / MODEL_FILE


def load_package(folder: Path, config_override: LocalizerConfig | None = None) -> Package:
    """Read and cross-check a package folder; raises ManifestError on anything inconsistent."""
    folder = Path(folder)
    model_path = folder / MODEL_FILE
    manifest = verify_weights(model_path) if model_path.is_file() else read_manifest(model_path)
    extra = manifest.extra
    if extra.get("localizer") != KIND or manifest.input.kind != "scan_hits":
        raise ManifestError(f"{model_path}: not a geometric localizer package (input kind "
                            f"{manifest.input.kind!r}, localizer {extra.get('localizer')!r})")
    parts = {}
    for key in ("court", "camera", "config"):
        path = folder / str(extra.get(f"{key}_file", ""))
        if not path.is_file():
            raise ManifestError(f"{folder}: package part {path.name!r} ({key}) is missing")
        if _sha(path) != extra.get(f"{key}_sha256"):
            raise ManifestError(f"{path}: does not match the sha256 in the package manifest")
        parts[key] = path
    court = load_court(parts["court"])
    camera = load_camera(parts["camera"])
    config = config_override or LocalizerConfig.model_validate(json.loads(parts["config"].read_text()))
    return Package(folder=folder, manifest=manifest, court=court, camera=camera, config=config)


def bundled_root() -> Path:
    """The folder of the packages shipped with courtloc (models/ in the source tree)."""
    import importlib.resources

    return Path(str(importlib.resources.files("courtloc.models")))


def bundled_packages() -> dict[tuple[str, str], Path]:
    """(court, camera) of each shipped package's manifest -> its folder."""
    out: dict[tuple[str, str], Path] = {}
    for folder in sorted(p for p in bundled_root().iterdir() if (p / MODEL_FILE).is_file()):
        manifest = read_manifest(folder / MODEL_FILE)
        out.setdefault((manifest.court, manifest.camera), folder)
    return out


def bundled_package(court: str, camera: str) -> Path:
    """The shipped package built for this court and camera; ManifestError naming what ships otherwise."""
    packages = bundled_packages()
    if (court, camera) not in packages:
        shipped = ", ".join(f"{c} / {m}" for c, m in sorted(packages)) or "none"
        raise ManifestError(f"no bundled localizer package for court {court!r} with camera {camera!r} (shipped: "
                            f"{shipped}); build one with `courtloc localizer build --court {court} --camera {camera}` "
                            f"and push it")
    return packages[(court, camera)]

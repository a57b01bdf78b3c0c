"""A geometric-localizer package: one folder that is everything the robot needs to localise.

    model.onnx       hits -> floor points (the camera as a per-pixel table), manifest in metadata_props
    court.json       the court model (courtloc.sim.court format): the distance field is built from it at load
    camera.json      the camera model (courtloc.sim.camera format): the fit's per-hit error model
    localizer.json   LocalizerConfig (robust fit, quality thresholds, search, symmetry mode)
    golden.npz       golden inputs: scan hits of twin frames at known poses (localizer/golden.py)
    README.md        what it is and how well it did (evaluation report)

The manifest names the three JSON files (extra.court_file ...) and the golden file (golden), with
their sha256, so a package whose parts do not belong together is refused at load. A part is a plain
file name inside the package folder (manifest.package_part).
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.manifest import (InputSpec, Manifest, ManifestError, OutputSpec, TensorSpec, TrainingData,
                                         attach_manifest, package_part, read_manifest, runtime_preprocessing,
                                         verify_weights)
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
# The accuracy a geometric package states on its golden frames (twin frames, tracked from the true pose):
# the bundled default's worst golden frame is a few cm off (docs/pit_tools.md); a package past these is broken.
GOLDEN_POSITION_M = 0.05
GOLDEN_YAW_DEG = 1.0


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def build_package(out_dir: Path, court: Court, camera: CameraModel, config: LocalizerConfig | None = None,
                  name: str = "courtloc-geometric", version: int = 1,
                  metrics: dict[str, dict[str, float]] | None = None,
                  training_data: TrainingData | None = None,
                  golden_position_m: float = GOLDEN_POSITION_M, golden_yaw_deg: float = GOLDEN_YAW_DEG) -> Manifest:
    """Write a package folder; returns the manifest stored in its model.onnx.

    Its golden inputs are rendered here, and the built package is checked against the accuracy it
    states on them (golden_position_m, golden_yaw_deg): ValueError when it misses it."""
    import onnx

    from courtloc.localizer.golden import GOLDEN_FILE
    from courtloc.localizer.golden_build import check_built, render_golden, write_golden

    config = config or LocalizerConfig()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / COURT_FILE).write_text(court.model_dump_json(indent=1))
    (out_dir / CAMERA_FILE).write_text(camera.model_dump_json(indent=1))
    (out_dir / CONFIG_FILE).write_text(config.model_dump_json(indent=1))
    frames = render_golden(court, camera)
    golden = write_golden(out_dir / GOLDEN_FILE, frames, golden_position_m, golden_yaw_deg)
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
        training_data=training_data, metrics=metrics or {}, golden=golden,
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
    run = check_built(out_dir / MODEL_FILE, frames, golden)
    log.info("wrote localizer package %s (%s / %s); golden position error max %.4f m, yaw max %.3f deg",
             out_dir, court.name, camera.name, max(run.position_error_m), run.max_yaw_error_deg() or 0.0)
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
    parts = {key: package_part(folder, extra.get(f"{key}_file"), extra.get(f"{key}_sha256"), key)
             for key in ("court", "camera", "config")}
    court = load_court(parts["court"])
    camera = load_camera(parts["camera"])
    config = config_override or LocalizerConfig.model_validate(json.loads(parts["config"].read_text()))
    return Package(folder=folder, manifest=manifest, court=court, camera=camera, config=config)

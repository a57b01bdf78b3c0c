"""Building a geometric-localizer package folder (the layout is `courtloc.localizer.package`'s)."""
from __future__ import annotations

import logging
from pathlib import Path

import onnx

from courtloc.lab.golden_build import MIN_GOLDEN_FRAMES, check_built, informative_frames, render_golden, write_golden
from courtloc.lab.onnx_graph import INPUT, OUTPUT, build_graph
from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.golden import GOLDEN_FILE
from courtloc.localizer.manifest import (
    MODEL_FILE,
    InputSpec,
    Manifest,
    OutputSpec,
    TensorSpec,
    TrainingData,
    attach_manifest,
    runtime_preprocessing,
)
from courtloc.localizer.package import (
    CAMERA_FILE,
    CONFIG_FILE,
    COURT_FILE,
    GOLDEN_POSITION_M,
    GOLDEN_YAW_DEG,
    KIND,
    file_sha256,
)
from courtloc.localizer.projection import build_floor_table
from courtloc.world.camera import CameraModel
from courtloc.world.court import Court

log = logging.getLogger(__name__)


def build_package(out_dir: Path, court: Court, camera: CameraModel, config: LocalizerConfig | None = None,
                  name: str = "courtloc-geometric", version: int = 1,
                  metrics: dict[str, dict[str, float]] | None = None,
                  training_data: TrainingData | None = None,
                  golden_position_m: float = GOLDEN_POSITION_M, golden_yaw_deg: float = GOLDEN_YAW_DEG) -> Manifest:
    """Write a package folder; returns the manifest stored in its model.onnx.

    Its golden inputs are rendered here, and the built package is checked against the accuracy it
    states on them (golden_position_m, golden_yaw_deg): ValueError when it misses it."""
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
            "court_file": COURT_FILE, "court_sha256": file_sha256(out_dir / COURT_FILE),
            "camera_file": CAMERA_FILE, "camera_sha256": file_sha256(out_dir / CAMERA_FILE),
            "config_file": CONFIG_FILE, "config_sha256": file_sha256(out_dir / CONFIG_FILE),
            "edge_offset_px": config.edge_offset_px,
            "symmetry": config.symmetry, "half": config.half,
        },
    )
    final = attach_manifest(model, manifest)
    onnx.save(model, str(out_dir / MODEL_FILE))
    # A golden pose this camera sees only as a degenerate view (a low or steep camera facing parallel lines)
    # says nothing about the package: it is left out, as long as enough informative views remain.
    kept = informative_frames(out_dir / MODEL_FILE, frames, golden)
    if len(kept) < len(frames):
        dropped = [frames[i].pose for i in range(len(frames)) if i not in kept]
        if len(kept) < MIN_GOLDEN_FRAMES:
            check_built(out_dir / MODEL_FILE, frames, golden)  # raises, naming every frame it misses
        log.info("golden poses %s give this camera no informative view: left out", dropped)
        frames = [frames[i] for i in kept]
        golden = write_golden(out_dir / GOLDEN_FILE, frames, golden_position_m, golden_yaw_deg)
        final = attach_manifest(model, final.model_copy(update={"golden": golden}))
        onnx.save(model, str(out_dir / MODEL_FILE))
    run = check_built(out_dir / MODEL_FILE, frames, golden)
    log.info("wrote localizer package %s (%s / %s); golden position error max %.4f m, yaw max %.3f deg",
             out_dir, court.name, camera.name, max(run.position_error_m), run.max_yaw_error_deg() or 0.0)
    return final

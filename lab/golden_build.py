"""Making a package's golden inputs (build side: renders the digital twin; the robot only reads them).

Twin frames of the package's court seen by its camera at known poses, through the real preprocess
pipeline, written as golden.npz (format: localizer/golden.py). The builder then checks the model
it built against the accuracy it states, so a package never ships a claim its own model breaks.
"""
from __future__ import annotations

import math
from pathlib import Path

from courtloc.localizer.golden import GOLDEN_FILE, GoldenFrame, GoldenRun, run_golden, save_golden
from courtloc.localizer.manifest import GoldenSpec, sha256_of
from courtloc.localizer.predictor import load_predictor
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.sim.render import Renderer

# Poses spread over both halves of the court, each facing enough lines for a valid fix (x, y, yaw); every
# court we ship contains them.
MIN_GOLDEN_FRAMES = 3  # the infer stage's default golden_min_frames
GOLDEN_POSES: tuple[tuple[float, float, float], ...] = (
    (-2.5, 1.0, 3.0), (2.0, -1.5, 0.4), (3.5, 1.8, -0.3), (-1.0, -2.0, 2.4), (1.0, 2.0, -1.2), (0.5, -0.5, 0.0),
)


def render_golden(court, camera, poses=GOLDEN_POSES) -> list[GoldenFrame]:  # noqa: ANN001 - world Court, CameraModel
    renderer = Renderer(court, camera)
    preprocessor = Preprocessor(PreprocessConfig(frame_width=camera.width, frame_height=camera.height))
    return [GoldenFrame(preprocessor.process(renderer.render(pose)), camera.width, camera.height,
                        tuple(float(v) for v in pose)) for pose in poses]


def write_golden(path: Path, frames: list[GoldenFrame], max_position_error_m: float,
                 max_yaw_error_deg: float | None) -> GoldenSpec:
    """Save the frames; the manifest entry naming them (as `golden.npz` in the package) and the stated accuracy."""
    save_golden(path, frames)
    return GoldenSpec(file=GOLDEN_FILE, sha256=sha256_of(path), n_frames=len(frames),
                      max_position_error_m=max_position_error_m, max_yaw_error_deg=max_yaw_error_deg)


def breaches(run: GoldenRun, spec: GoldenSpec) -> list[str]:
    """Why `run` does not meet the accuracy `spec` states, one line per frame; empty when it does."""
    return [problem for i in range(len(run.position_error_m)) for problem in breaches_of(run, spec, i)]


def informative_frames(model_path: Path, frames: list[GoldenFrame], spec: GoldenSpec) -> list[int]:
    """Indices of the frames the built model answers within the accuracy `spec` states (valid, on the pose)."""
    run = run_golden(load_predictor(model_path), frames)
    return [i for i in range(len(frames)) if not breaches_of(run, spec, i)]


def breaches_of(run: GoldenRun, spec: GoldenSpec, i: int) -> list[str]:
    """Why frame `i` of `run` misses the accuracy `spec` states; empty when it meets it."""
    error, yaw_error, valid = run.position_error_m[i], run.yaw_error_deg[i], run.valid[i]
    problems = []
    if not valid:
        problems.append(f"frame {i}: not valid")
    if not math.isfinite(error) or error > spec.max_position_error_m:
        problems.append(f"frame {i}: position error {error:.3f} m > {spec.max_position_error_m} m")
    if spec.max_yaw_error_deg is not None and yaw_error is not None and yaw_error > spec.max_yaw_error_deg:
        problems.append(f"frame {i}: yaw error {yaw_error:.2f} deg > {spec.max_yaw_error_deg} deg")
    return problems


def check_built(model_path: Path, frames: list[GoldenFrame], spec: GoldenSpec) -> GoldenRun:
    """Run the built model on its golden frames; ValueError when it misses its own stated accuracy."""

    run = run_golden(load_predictor(model_path), frames)
    problems = breaches(run, spec)
    if problems:
        raise ValueError(f"{model_path}: the built model misses the accuracy it states: " + "; ".join(problems))
    return run

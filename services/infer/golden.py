"""Golden inputs for validating a candidate model: twin frames of its court, seen by its camera,
at known poses, through the real preprocess stage. Made once per (court, camera) and kept."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

# Poses spread over the court, facing lines (x, y, yaw); every court we ship contains them.
GOLDEN_POSES: tuple[tuple[float, float, float], ...] = (
    (-2.5, 1.0, 3.0), (2.0, -1.5, 0.4), (3.5, 1.8, -0.3), (-1.0, -2.0, 2.4), (0.8, 0.5, 1.57),
)


@dataclass(frozen=True)
class GoldenFrame:
    hits: np.ndarray
    width: int
    height: int
    pose: tuple[float, float, float]


class GoldenSets:
    """Golden frames per (court, camera), rendered on first use."""

    def __init__(self) -> None:
        self._sets: dict[tuple[str, str], list[GoldenFrame]] = {}

    def get(self, court_name: str, camera_name: str) -> list[GoldenFrame]:
        key = (court_name, camera_name)
        if key not in self._sets:
            self._sets[key] = _render_golden(court_name, camera_name)
        return self._sets[key]


def _render_golden(court_name: str, camera_name: str) -> list[GoldenFrame]:
    # The twin renders golden frames on the robot until packages ship their own golden inputs (issue 16).
    from courtloc.sim.render import Renderer

    # The twin renders golden frames on the robot until packages ship their own golden inputs (issue 16).

    camera = load_camera(camera_name)
    renderer = Renderer(load_court(court_name), camera)
    preprocessor = Preprocessor(PreprocessConfig(frame_width=camera.width, frame_height=camera.height))
    frames = []
    for pose in GOLDEN_POSES:
        image = renderer.render(pose)
        frames.append(GoldenFrame(preprocessor.process(image), camera.width, camera.height, pose))
    return frames

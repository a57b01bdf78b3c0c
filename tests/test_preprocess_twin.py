"""Fast scan == reference on digital-twin frames from `courtloc.sim`."""
from __future__ import annotations

import numpy as np
import pytest

from courtloc.scan.config import PreprocessConfig
from courtloc.scan.hsv_mask import white_mask
from courtloc.scan.preprocessor import Preprocessor
from courtloc.scan.reference_scan import reference_preprocess
from courtloc.sim.render import Renderer, RenderOptions
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

POSES = [(0.0, 0.0, 0.0), (2.0, 1.0, 0.5), (-3.0, -2.0, 2.5), (4.0, -1.0, -1.0)]


@pytest.fixture(scope="module")
def twin() -> Renderer:
    return Renderer(load_court("seed-gazebo"), load_camera("seed-gazebo"))


@pytest.mark.parametrize("pose_index", range(len(POSES)))
def test_fast_equals_reference_on_twin_frames(twin: Renderer, pose_index: int) -> None:
    config = PreprocessConfig()
    preprocessor = Preprocessor(config)
    clean = twin.render(POSES[pose_index])
    randomised = twin.render(POSES[pose_index], RenderOptions.randomised(), np.random.default_rng(pose_index))
    for frame in (clean, randomised):
        hits = preprocessor.process(frame)
        assert len(hits) > 30  # the court's lines are found with the default HSV ranges
        np.testing.assert_array_equal(hits, reference_preprocess(frame, config))
    # The floor itself is not white: the lines are a small part of the mask.
    assert (white_mask(clean, config.hsv_ranges) > 0).mean() < 0.2

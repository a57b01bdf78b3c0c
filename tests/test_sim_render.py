"""Renderer: geometry of the rendered floor, the preprocess stage finds the lines' far edges, randomisation."""
from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial import cKDTree

from courtloc.sim.render import OccluderOptions, Renderer, RenderOptions
from courtloc.world.camera import CameraModel, load_camera
from courtloc.world.court import load_court


@pytest.fixture(scope="module")
def seed_renderer() -> Renderer:
    court = load_court("seed-gazebo")
    return Renderer(court, load_camera(court.default_camera))


def _is_white(pixel: np.ndarray) -> bool:
    return bool(pixel.min() > 200 and int(pixel.max()) - int(pixel.min()) < 30)


def test_frame_shape_and_known_floor_points(seed_renderer):
    pose = (-2.0, 0.3, 0.0)  # facing +x, the centre line 2 m ahead
    frame = seed_renderer.render(pose)
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    cam = seed_renderer.camera
    on_line, on_floor = cam.court_to_pixel(np.array([[0.0, 0.3], [-1.0, 0.3]]), pose)
    assert _is_white(frame[int(round(on_line[1])), int(round(on_line[0]))])
    court_bgr = np.array(seed_renderer.court.rgb("court")[::-1])
    assert np.abs(frame[int(round(on_floor[1])), int(round(on_floor[0]))].astype(int) - court_bgr).max() <= 2
    # Above the horizon there is arena, not floor.
    assert not _is_white(frame[5, 320]) and np.abs(frame[5, 320].astype(int) - court_bgr).max() > 10


def test_preprocess_finds_far_edges_of_the_painted_lines(seed_renderer):
    from courtloc.scan.config import PreprocessConfig
    from courtloc.scan.preprocessor import Preprocessor

    court, cam = seed_renderer.court, seed_renderer.camera
    edges, normals = court.white_edges(0.01)
    tree = cKDTree(edges)
    pre = Preprocessor(PreprocessConfig())
    for pose in [(-2.0, 0.3, 0.1), (1.0, -2.0, 0.7), (3.0, 2.5, -2.5)]:
        hits = pre.process(seed_renderer.render(pose))
        assert len(hits) > 30
        assert np.all(hits[:, 0] > cam.horizon_row() - 1)
        floor = cam.pixel_to_court(hits[:, [1, 0]].astype(float), pose)
        dist, nearest = tree.query(floor)
        # Within a pixel's footprint of a white edge, and on an edge that faces away from the camera.
        cam_xy = cam.pixel_to_court(np.array([[320.0, 479.0]]), pose)[0]
        facing = np.einsum("ij,ij->i", normals[nearest], edges[nearest] - cam_xy) > 0
        rng_m = np.hypot(*(floor - cam_xy).T) + 0.8
        pixel_footprint = rng_m ** 2 / (cam.fy * cam.mount.height)
        assert np.median(dist / pixel_footprint) < 1.0
        assert facing.mean() > 0.95


def test_same_seed_same_frame_and_randomisation_changes_it(seed_renderer):
    options = RenderOptions.randomised()
    pose = (0.5, -1.0, 2.0)
    a = seed_renderer.render(pose, options, np.random.default_rng(3))
    b = seed_renderer.render(pose, options, np.random.default_rng(3))
    c = seed_renderer.render(pose, options, np.random.default_rng(4))
    clean = seed_renderer.render(pose)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a.astype(int) - c).mean() > 1.0
    assert np.abs(a.astype(int) - clean).mean() > 1.0


def test_occluders_cover_part_of_the_floor(seed_renderer):
    pose = (-2.0, 0.0, 0.0)
    options = RenderOptions(occluders=OccluderOptions(max_count=4, kinds=["robot"], distance_m=(1.0, 2.0)))
    clean = seed_renderer.render(pose)
    changed = [np.any(seed_renderer.render(pose, options, np.random.default_rng(s)) != clean, axis=2).mean()
               for s in range(6)]
    assert max(changed) > 0.02  # some seeds draw a robot of visible size


def test_distorted_camera_renders_floor_where_the_model_projects_it():
    court = load_court("robocon2025")
    cam = load_camera("robocon2025").model_copy(update={"k1": -0.2, "k2": 0.03})
    renderer = Renderer(court, cam)
    pose = (-1.0, 0.0, 0.0)  # centre line 1 m ahead of the robot, 0.8 m ahead of the camera
    frame = renderer.render(pose)
    for y in (-0.4, 0.0, 0.4):
        u, v = cam.court_to_pixel(np.array([[0.0, y]]), pose)[0]
        assert _is_white(frame[int(round(v)), int(round(u))])


def test_bad_options_name_the_field():
    with pytest.raises(ValidationError, match="exposure_gain"):
        RenderOptions(exposure_gain=(1.3, 1.0))
    with pytest.raises(ValidationError, match="extra"):
        RenderOptions(glare=1.0)


def test_camera_without_floor_is_refused_before_rendering():
    with pytest.raises(ValidationError, match="horizon"):
        CameraModel(fx=300, fy=300, cx=320, cy=240, mount={"height": 0.5, "pitch": -1.0})


def test_warm_up_builds_every_asset_a_randomised_frame_can_draw() -> None:
    """A camera rendering in real time warms up before its clock starts: afterwards no frame builds an asset
    (each cost 50-250 ms on first use, so the first frames of a run missed slots)."""
    renderer = Renderer(load_court("robocon2025"), load_camera("robocon2025"))
    options = RenderOptions.randomised()
    renderer.warm_up(options)
    built = (len(renderer._variants), len(renderer._light_fields), len(renderer._noise_banks))
    assert built[0] == options.floor_variants and built[1] > 0 and built[2] > 0
    for index in range(60):
        renderer.render((1.0, -2.0, 0.3 * index), options, np.random.default_rng([3, index]))
    assert (len(renderer._variants), len(renderer._light_fields), len(renderer._noise_banks)) == built

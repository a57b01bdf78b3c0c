"""The simulated camera is the twin's own camera stage: the robot's camera stage has no "sim", the tools start
the twin's entry point for it, and a bad [camera.sim] table stops them before anything starts."""
from __future__ import annotations

import pytest

from courtloc.bench_procstats import stage_of_argv
from courtloc.common.config_loader import ConfigError
from courtloc.services.camera.config import CameraConfig, SimRoute
from courtloc.services.camera.service import CameraService
from courtloc.services.camera.sources import make_source
from courtloc.services.deployment import DeploymentConfig
from courtloc.sim.camera_stage import SimCameraService, SimFrameSource, sim_source_config
from courtloc.sim.source import SimSourceConfig
from courtloc.stage_cli import SIM_CAMERA_MODULE, stage_argv, stage_module


def test_the_robot_camera_stage_has_no_sim_and_says_where_it_is() -> None:
    assert "sim" not in CameraService.sources
    with pytest.raises(ValueError, match="courtloc.sim.camera_stage"):
        make_source(CameraConfig(source="sim"), CameraService.sources)
    # the twin's stage is the same service with one more kind
    assert SimCameraService.name == CameraService.name and SimCameraService.sources["sim"] is SimFrameSource
    assert {k: v for k, v in SimCameraService.sources.items() if k != "sim"} == dict(CameraService.sources)


def test_a_simulated_camera_runs_the_twins_entry_point() -> None:
    sim = DeploymentConfig()  # the built-in deployment: the simulated camera
    assert stage_module("camera", sim) == SIM_CAMERA_MODULE == "courtloc.sim.camera_stage"
    assert stage_argv("camera", None, sim)[1:3] == ["-m", SIM_CAMERA_MODULE]
    assert stage_module("infer", sim) == "courtloc.services.infer"
    device = DeploymentConfig.model_validate({"camera": {"source": "device"}})
    assert stage_module("camera", device) == "courtloc.services.camera"
    # the bench still tells the camera's process by its command line
    assert stage_of_argv(["python", "-m", SIM_CAMERA_MODULE, "--config", "x.toml"]) == "camera"


def test_a_bad_sim_table_is_named_before_anything_starts() -> None:
    config = DeploymentConfig.model_validate({"camera": {"sim": {"speed_mps": -1, "bogus": 1}}})
    with pytest.raises(ConfigError) as err:
        stage_module("camera", config)
    assert "field camera.sim.speed_mps" in str(err.value) and "field camera.sim.bogus" in str(err.value)


def test_the_deployment_reads_the_twins_own_route_and_the_twin_its_table() -> None:
    twin, route = SimSourceConfig(), SimRoute()
    assert (twin.trajectory, twin.waypoints, twin.start) == (route.trajectory, route.waypoints, route.start)
    camera = CameraConfig(fps=12.0, sim={"court": "robocon2025", "seed": 4})
    assert sim_source_config(camera) == SimSourceConfig(court="robocon2025", seed=4, fps=12.0)


def test_a_missed_slot_is_time_the_twin_robot_kept_moving_through() -> None:
    """The twin's frame shows the slot it was read in: after a late read it shows the robot where it is by
    then, as a real camera would, not the next frame of a world that waited for the renderer."""
    period_ns = round(1e9 / 30.0)
    reads = iter([5_000, 5_000 + period_ns, 5_000 + 3 * period_ns + 2_000_000, 5_000 + 3 * period_ns + 2_100_000])
    camera = CameraConfig(fps=30.0, sim={"trajectory": "random_walk", "speed_mps": 2.0})
    source = SimFrameSource(camera, clock=lambda: next(reads))
    source.open()
    try:
        shown = [source.read().truth for _ in range(4)]
        expected = [source._sim.pose_at_index(i) for i in (0, 1, 3, 4)]  # slot 2 was missed; a read never repeats
    finally:
        source.close()
    for got, want in zip(shown, expected):
        assert got == pytest.approx(tuple(float(v) for v in want))

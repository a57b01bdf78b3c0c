"""A split deployment on one machine: two routers (the "robot" and the "laptop") joined router to router,
the camera on one side sending JPEG, preprocess on the other, and the chain still works across the hop."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router, start_stage, write_config

from courtloc.services.deployment import load_deployment

pytestmark = pytest.mark.integration

PROFILES = Path(__file__).resolve().parents[1] / "deploy" / "configs"


def _court_images(folder: Path, n: int = 4) -> Path:
    """640x480 frames with white court lines below the paper's 200-row crop, so the scan has hits."""
    folder.mkdir()
    for i in range(n):
        image = np.full((480, 640, 3), 60, np.uint8)
        cv2.line(image, (0, 300 + 10 * i), (639, 320 + 10 * i), (255, 255, 255), 4)
        cv2.line(image, (200 + 20 * i, 479), (320, 220), (255, 255, 255), 4)
        cv2.imwrite(str(folder / f"{i}.png"), image)
    return folder


def _start_router_joining(tmp_path: Path, port: int, upstream: int) -> Proc:
    config = tmp_path / "router_b.toml"
    # No shared memory on the "laptop": on one machine, that is what makes the hop behave like Wi-Fi.
    config.write_text(f'[zenoh]\nshared_memory = false\n'
                      f'[router]\nlisten = ["{endpoint(port)}"]\nconnect = ["{endpoint(upstream)}"]\n')
    router = Proc([*PYTHON, "router", "--config", str(config)]).start()
    router.wait_line("router listening")
    return router


def test_chain_crosses_two_routers(tmp_path: Path) -> None:
    port_robot, port_laptop = free_port(), free_port()
    robot_router = start_router(port_robot)
    laptop_router = _start_router_joining(tmp_path, port_laptop, port_robot)
    folder = _court_images(tmp_path / "frames")
    camera_cfg = write_config(tmp_path / "robot.toml", port_robot, health_period_s=0.2, body=f"""
[camera]
source = "folder"
fps = 15
encoding = "jpeg"
[camera.folder]
path = "{folder}"
pattern = "*.png"
""")
    laptop_cfg = write_config(tmp_path / "laptop.toml", port_laptop, zenoh_extra="shared_memory = false",
                              health_period_s=0.2)
    on_laptop, on_robot = BusClient(port_laptop), BusClient(port_robot)
    on_laptop.subscribe("camera/frame")
    on_robot.subscribe("preprocess/edges")
    on_robot.subscribe("preprocess/health")
    on_robot.subscribe("camera/health")
    camera = start_stage("camera", camera_cfg)
    preprocess = start_stage("preprocess", laptop_cfg)
    try:
        on_robot.wait_alive("preprocess")  # liveliness crosses the hop too
        frame = on_laptop.wait_for("camera/frame", timeout=30)
        assert frame.encoding == "jpeg", "frames cross the hop as JPEG"
        edges = on_robot.wait_for("preprocess/edges", lambda m: m.header.valid, timeout=30)
        assert [s.stage for s in edges.header.stamps] == ["camera", "preprocess"]
        assert edges.n_hits > 0 and (edges.width, edges.height) == (640, 480)
        later = on_robot.wait_for("preprocess/edges", lambda m: m.header.seq > edges.header.seq + 3, timeout=30)
        assert later.header.valid
        # The camera wrote its frames into shared memory; across the hop the same topic arrived as bytes.
        health = on_robot.wait_for("preprocess/health", lambda h: h.detail.get("frames_via_bytes", 0) > 0)
        assert health.detail["frames_via_shm"] == 0
        camera_health = on_robot.wait_for("camera/health", lambda h: h.detail.get("frames_in_shm", 0) > 0)
        assert camera_health.detail["frames_as_bytes"] == 0
    finally:
        on_laptop.close()
        on_robot.close()
        for proc in (preprocess, camera):
            assert proc.stop() == 0, proc.output()
        laptop_router.stop()
        robot_router.stop()


def test_shipped_profiles_place_stages_as_documented() -> None:
    robot = load_deployment(PROFILES / "robot.toml")
    pit = load_deployment(PROFILES / "pit.toml")
    offload = load_deployment(PROFILES / "offload.toml")
    assert robot.launcher.run_router and robot.camera.encoding == "bgr8"
    assert not pit.launcher.run_router and not offload.launcher.run_router, "the laptop joins the robot's router"
    assert "infer" in offload.launcher.services and "camera" not in offload.launcher.services
    assert offload.camera.encoding == "jpeg", "frames crossing Wi-Fi are JPEG"
    assert all(ep.startswith(("tcp/", "tls/")) and "127.0.0.1" not in ep for ep in offload.zenoh.connect)

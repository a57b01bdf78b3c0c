"""The camera unplugged mid-stream and plugged back (its image folder removed, then recreated):
the stage reports the fault in its health, keeps its process, and streams the new images."""
from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from buskit import BusClient, folder_camera_toml, free_port, start_router, start_stage, write_config

pytestmark = pytest.mark.integration


def _fill(folder: Path, value: int) -> None:
    folder.mkdir()
    for i in range(3):
        cv2.imwrite(str(folder / f"{i}.png"), np.full((24, 32, 3), value, np.uint8))


def test_camera_unplugged_and_back(tmp_path: Path) -> None:
    port = free_port()
    folder = tmp_path / "camera"
    _fill(folder, 10)
    config = write_config(tmp_path / "cam.toml", port,
                          folder_camera_toml(folder, extra="reopen_backoff_s = 0.1\nreopen_backoff_max_s = 0.2"),
                          health_period_s=0.2)
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("camera/frame")
    client.subscribe("camera/health")
    camera = start_stage("camera", config)
    try:
        first = client.wait_for("camera/frame", timeout=60)
        assert np.frombuffer(first.data, np.uint8).mean() == pytest.approx(10, abs=1)
        pid = camera.pid

        shutil.rmtree(folder)  # unplugged
        health = client.wait_for("camera/health", lambda h: h.detail.get("source_errors", 0) >= 2, timeout=30)
        assert "not found" in health.last_error or "cannot decode" in health.last_error
        assert camera.alive()

        _fill(folder, 200)  # plugged back, showing something else
        back = client.wait_for("camera/frame", lambda m: np.frombuffer(m.data, np.uint8).mean() > 150, timeout=30)
        assert back.header.valid and back.header.seq > first.header.seq, "same stream, counting on"
        assert camera.alive() and camera.pid == pid
    finally:
        client.close()
        assert camera.stop() == 0, camera.output()
        router.stop()

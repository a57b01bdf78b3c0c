"""Stages survive the router coming late or going away, without restarting themselves."""
from __future__ import annotations

from pathlib import Path

import pytest
from buskit import (
    BusClient,
    endpoint,
    folder_camera_toml,
    free_port,
    start_router,
    start_stage,
    write_config,
    write_line_frames,
)

pytestmark = pytest.mark.integration


def _camera_config(tmp_path: Path, port: int) -> Path:
    folder = write_line_frames(tmp_path / "frames", size=(24, 32))
    return write_config(tmp_path / "cam.toml", port, folder_camera_toml(folder))


def test_stage_started_before_router_connects_when_it_appears(tmp_path: Path) -> None:
    port = free_port()
    config = _camera_config(tmp_path, port)
    camera = start_stage("camera", config)
    try:
        camera.wait_line(f"waiting for a router at {endpoint(port)}")  # waiting, not dead, and says for what
        assert camera.alive()
        router = start_router(port)
        client = BusClient(port)
        client.subscribe("camera/frame")
        try:
            assert client.wait_for("camera/frame").header.valid
        finally:
            client.close()
            router.stop()
    finally:
        camera.stop()


def test_router_restart_mid_stream(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    camera = start_stage("camera", _camera_config(tmp_path, port))
    client = BusClient(port)
    client.subscribe("camera/frame")
    try:
        first = client.wait_for("camera/frame")
        router.kill()
        router = start_router(port)
        client.drain("camera/frame")
        resumed = client.wait_for("camera/frame", lambda m: m.header.seq > first.header.seq + 5, timeout=30)
        assert resumed.header.valid
        assert camera.alive(), "the stage resumed without restarting"
    finally:
        client.close()
        camera.stop()
        router.stop()

"""The camera stage against a real router, as its own process."""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from buskit import BusClient, folder_camera_toml, free_port, start_router, start_stage, write_config

pytestmark = pytest.mark.integration


def _image_folder(tmp_path: Path, n: int = 6) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    rows = ["image_filename,x,y,orientation_z"]
    for i in range(n):
        image = np.full((48, 64, 3), 40 * i, np.uint8)
        cv2.imwrite(str(folder / f"f{i:03d}.png"), image)
        rows.append(f"f{i:03d}.png,{i * 0.5},{-i * 0.25},{math.sin(0.1 * i / 2)}")
    (folder / "poses.csv").write_text("\n".join(rows) + "\n")
    return folder


def _folder_config(tmp_path: Path, port: int, folder: Path, encoding: str = "bgr8") -> Path:
    return write_config(tmp_path / "cam.toml", port, f"""
[camera]
source = "folder"
fps = 30
encoding = "{encoding}"
[camera.folder]
path = "{folder}"
csv = "{folder / 'poses.csv'}"
pattern = "*.png"
""")


@pytest.mark.parametrize("encoding", ["bgr8", "jpeg"])
def test_folder_source_publishes_frames_and_truth(tmp_path: Path, encoding: str) -> None:
    port = free_port()
    folder = _image_folder(tmp_path)
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("camera/frame")
    client.subscribe("camera/ground_truth")
    camera = start_stage("camera", _folder_config(tmp_path, port, folder, encoding))
    try:
        frame = client.wait_for("camera/frame")
        assert frame.header.valid and frame.encoding == encoding
        assert (frame.width, frame.height) == (64, 48)
        if encoding == "bgr8":
            pixels = np.frombuffer(frame.data, np.uint8).reshape(48, 64, 3)
        else:
            pixels = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_COLOR)
        assert abs(int(pixels.mean()) - 40 * (frame.header.seq % 6)) <= 2, "the frame is the file's image"
        truth = client.wait_for("camera/ground_truth", lambda m: m.header.seq % 6 == 3)
        assert truth.x == pytest.approx(1.5) and truth.y == pytest.approx(-0.75)
        assert truth.yaw == pytest.approx(0.3)
        seqs = [m.header.seq for m, _ in zip(client.messages("camera/frame"), range(10))]
        assert seqs == sorted(seqs) and len(set(seqs)) == 10
    finally:
        client.close()
        assert camera.stop() == 0, camera.output()
        router.stop()


def test_missing_folder_is_retried_not_fatal(tmp_path: Path) -> None:
    """A camera that is not there is reopened with back-off; plugging it in makes frames flow."""
    port = free_port()
    folder = tmp_path / "later"
    config = write_config(tmp_path / "cam.toml", port,
                          folder_camera_toml(folder, fps=30, extra="reopen_backoff_s = 0.1\nreopen_backoff_max_s = 0.2"),
                          health_period_s=0.2)
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("camera/frame")
    client.subscribe("camera/health")
    camera = start_stage("camera", config)
    try:
        health = client.wait_for("camera/health", lambda h: h.detail.get("source_errors", 0) >= 2)
        assert "not found" in health.last_error
        folder.mkdir()
        cv2.imwrite(str(folder / "a.png"), np.zeros((10, 10, 3), np.uint8))
        frame = client.wait_for("camera/frame")
        assert frame.width == 10 and camera.alive()
    finally:
        client.close()
        camera.stop()
        router.stop()

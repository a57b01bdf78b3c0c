"""`courtloc dataset capture`: frames paired with the nearest-in-time pose, written in the seed format."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router, start_stage, write_config

from courtloc.common import codec
from courtloc.common.messages import Frame, Header, Pose
from courtloc.recording.capture import NearestMatcher, orientation_z

ROBOT = "robot1"
MS = 1_000_000


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2, math.pi, -math.pi, 3.5, -4.0, 7.0])
def test_orientation_z_is_the_seed_convention(yaw: float) -> None:
    z = orientation_z(yaw)
    wrapped = math.atan2(math.sin(yaw), math.cos(yaw))
    if wrapped <= -math.pi + 1e-12:
        wrapped = math.pi  # (-pi, pi]: -pi is written as +pi
    assert math.cos(wrapped / 2) >= -1e-12, "w >= 0"
    assert 2 * math.asin(z) == pytest.approx(wrapped, abs=1e-9)


def test_nearest_matcher_picks_the_closest_stamp_within_tolerance() -> None:
    matcher: NearestMatcher[str, str] = NearestMatcher(tolerance_ns=20 * MS)
    for stamp in (0, 33, 66):
        matcher.add_truth(stamp * MS, f"t{stamp}")
    matcher.add_frame(10 * MS, "f10", arrival_s=0.0)
    matcher.add_frame(50 * MS, "f50", arrival_s=0.0)
    matcher.add_frame(60 * MS, "f60", arrival_s=0.0)
    matcher.add_frame(200 * MS, "f200", arrival_s=0.0)
    # f50 and f60 could still meet a truth up to 70 and 80 ms; f200 has none yet: they wait.
    assert matcher.ready(now_s=0.1) == [("f10", "t0")]
    matcher.add_truth(90 * MS, "t90")
    assert matcher.ready(now_s=0.2) == [("f50", "t66"), ("f60", "t66")]
    assert matcher.ready(now_s=5.0) == [("f200", None)], "decided without a pose once it waited long enough"


def _capture(port: int, out: Path, *extra: str) -> Proc:
    return Proc([*PYTHON, "dataset", "capture", "--out", str(out), "--connect", endpoint(port),
                 "--robot", ROBOT, *extra]).start()


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "pose_data.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert rows and list(rows[0]) == ["image_filename", "x", "y", "orientation_z"]
    return rows


@pytest.mark.integration
def test_capture_from_the_camera_and_its_ground_truth(tmp_path: Path) -> None:
    """The real camera stage (folder source with poses) feeds capture; every image gets its own pose."""
    folder = tmp_path / "frames"
    folder.mkdir()
    lines = ["image_filename,x,y,orientation_z"]
    for i in range(6):
        cv2.imwrite(str(folder / f"f{i}.png"), np.full((48, 64, 3), 40 * i, np.uint8))
        lines.append(f"f{i}.png,{i * 0.5},{-i * 0.25},{math.sin(0.2 * i / 2)}")
    (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    port = free_port()
    config = write_config(tmp_path / "cam.toml", port, f"""
[camera]
source = "folder"
fps = 20
[camera.folder]
path = "{folder}"
csv = "{folder / 'poses.csv'}"
pattern = "*.png"
""")
    router = start_router(port)
    out = tmp_path / "dataset"
    capture = _capture(port, out, "--n", "8")
    camera = start_stage("camera", config, verbose=False)
    try:
        capture.wait_line("capturing")
        assert capture.process is not None and capture.process.wait(60) == 0, capture.output()
    finally:
        capture.stop()
        camera.stop()
        router.stop()
    summary = json.loads(capture.lines[-1])
    assert summary["captured"] == 8
    rows = _rows(out)
    assert len(rows) == 8
    for row in rows:
        image = cv2.imread(str(out / "images" / row["image_filename"]), cv2.IMREAD_COLOR)
        index = round(float(row["x"]) / 0.5)
        assert abs(float(image.mean()) - 40 * index) <= 3, "the pose is the one of this very image"
        assert float(row["y"]) == pytest.approx(-index * 0.25)
        assert 2 * math.asin(float(row["orientation_z"])) == pytest.approx(0.2 * index, abs=1e-6)


@pytest.mark.integration
def test_capture_with_an_external_pose_topic_and_lag(tmp_path: Path) -> None:
    """A tracker publishing under its own robot id, 15 ms late; frames without a close pose are left out."""
    port = free_port()
    router = start_router(port)
    out = tmp_path / "dataset"
    capture = _capture(port, out, "--n", "4", "--truth-topic", "infer/pose", "--truth-robot", "tracker1",
                       "--tolerance-ms", "10", "--offset-ms", "15")
    robot, tracker = BusClient(port, ROBOT), BusClient(port, "tracker1")
    try:
        capture.wait_line("capturing")
        robot.wait_subscribed("camera/frame")
        tracker.wait_subscribed("infer/pose")
        base = 1_700_000_000_000 * MS
        for i in range(6):
            ok, jpeg = cv2.imencode(".jpg", np.full((24, 32, 3), 30 * i, np.uint8))
            stamp = base + i * 100 * MS
            frame = Frame(header=Header(robot_id=ROBOT, seq=i, capture_mono_ns=stamp, capture_wall_ns=stamp,
                                        valid=True), width=32, height=24, encoding="jpeg", data=jpeg.tobytes())
            robot.put_raw("camera/frame", codec.encode(frame))
            if i == 2:
                continue  # no pose for this frame at all
            lag = 15 * MS if i != 4 else 45 * MS  # frame 4's pose is 30 ms off the expected lag: too far
            pose = Pose(header=Header(robot_id="tracker1", seq=i, capture_mono_ns=stamp + lag,
                                      capture_wall_ns=stamp + lag), x=float(i), y=1.0, yaw=0.1 * i,
                        model_name="tracker", model_version=1, infer_ms=0.0)
            tracker.put_raw("infer/pose", codec.encode(pose))
        assert capture.process is not None and capture.process.wait(30) == 0, capture.output()
    finally:
        robot.close()
        tracker.close()
        capture.stop()
        router.stop()
    summary = json.loads(capture.lines[-1])
    assert summary["captured"] == 4 and summary["unmatched"] == 2
    rows = _rows(out)
    assert [float(r["x"]) for r in rows] == [0.0, 1.0, 3.0, 5.0]
    for row in rows:
        stored = (out / "images" / row["image_filename"]).read_bytes()
        image = cv2.imdecode(np.frombuffer(stored, np.uint8), cv2.IMREAD_COLOR)
        assert abs(float(image.mean()) - 30 * float(row["x"])) <= 3


def test_capture_refuses_a_folder_that_holds_a_dataset(tmp_path: Path) -> None:
    (tmp_path / "pose_data.csv").write_text("image_filename,x,y,orientation_z\n")
    capture = Proc([*PYTHON, "dataset", "capture", "--out", str(tmp_path), "--connect", "tcp/127.0.0.1:1"]).start()
    assert capture.process is not None and capture.process.wait(30) == 2
    assert "exists" in capture.output()

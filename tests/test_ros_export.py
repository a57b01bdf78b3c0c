"""`courtloc export rosbag2`: a recording as a ROS 2 bag, read back with the rosbags reader."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from courtloc.cli import main
from courtloc.common import codec
from courtloc.common.messages import Frame, Header, Pose, ShotSolution, StageStamp
from courtloc.recording.foxview import FoxgloveViews
from courtloc.recording.mcapfile import Limits, McapSeries
from courtloc.recording.recorder import record_item

pytest.importorskip("rosbags", reason="the ros extra")
from rosbags.highlevel import AnyReader  # noqa: E402

from courtloc.ros import types  # noqa: E402

ROBOT = "robot1"
T0 = 1_700_000_000_000_000_000
COV = [0.0004, 0.0001, 0.00002, 0.0001, 0.0009, 0.00003, 0.00002, 0.00003, 0.0001]


def _header(seq: int, stage: str, valid: bool = True) -> Header:
    wall = T0 + seq * 33_000_000
    return Header(robot_id=ROBOT, seq=seq, capture_mono_ns=seq, capture_wall_ns=wall, valid=valid,
                  stamps=[StageStamp(stage=stage, mono_ns=seq, wall_ns=wall)])


def _jpeg() -> bytes:
    import cv2

    ok, data = cv2.imencode(".jpg", np.full((8, 8, 3), 128, np.uint8))
    assert ok
    return data.tobytes()


@pytest.fixture()
def recording(tmp_path: Path) -> Path:
    out = tmp_path / "match.mcap"
    series = McapSeries(out, Limits(), {}, FoxgloveViews.load("seed-gazebo"))
    messages = [
        ("infer/pose", Pose(header=_header(1, "infer"), x=1.5, y=-2.0, yaw=0.3, model_name="m", model_version=1,
                            infer_ms=1.0, covariance=COV)),
        ("infer/pose", Pose(header=_header(2, "infer", valid=False), x=9.0, y=9.0, yaw=0.0, model_name="m",
                            model_version=1, infer_ms=1.0, reason="low_quality")),
        ("infer/pose", Pose(header=_header(3, "infer"), x=2.0, y=0.5, yaw=None, model_name="xy", model_version=1,
                            infer_ms=1.0)),
        ("camera/frame", Frame(header=_header(4, "camera"), width=8, height=8, encoding="jpeg", data=_jpeg())),
        ("camera/frame", Frame(header=_header(5, "camera"), width=4, height=2, encoding="bgr8", data=bytes(24))),
        ("shooter_bridge/solution", ShotSolution(header=_header(6, "shooter_bridge"), distance_m=4.2, bearing_rad=0.1,
                                                 rpm=2300.0, command="SET_RPM")),
        ("shooter_bridge/solution", ShotSolution(header=_header(7, "shooter_bridge", valid=False),
                                                 distance_m=float("nan"), rpm=0.0, command="HOLD",
                                                 reason="no_pose")),
    ]
    for i, (path, message) in enumerate(messages):
        series.write(record_item(path, ROBOT, codec.encode(message), T0 + i * 10_000_000, series.foxglove))
    series.close()
    return out


def _read(bag: Path) -> dict[str, list[tuple[str, int, object]]]:
    found: dict[str, list[tuple[str, int, object]]] = {}
    with AnyReader([bag], default_typestore=types.typestore()) as reader:
        for connection, timestamp, raw in reader.messages():
            found.setdefault(connection.topic, []).append(
                (connection.msgtype, timestamp, reader.deserialize(raw, connection.msgtype)))
    return found


def test_export_reads_back_with_the_rosbags_reader(recording: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    bag = tmp_path / "bag"
    with pytest.raises(SystemExit) as exit_info:
        main(["export", "rosbag2", str(recording), str(bag)])
    assert exit_info.value.code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["skipped"] == {"pose_not_valid": 1}
    found = _read(bag)
    poses = found["/courtloc/pose"]
    assert [m[0] for m in poses] == [types.POSE_COV] * 2, "the invalid pose is not exported"
    first = poses[0][2]
    assert (first.header.frame_id, first.pose.pose.position.x, first.pose.pose.position.y) == ("court", 1.5, -2.0)
    assert 2 * math.atan2(first.pose.pose.orientation.z, first.pose.pose.orientation.w) == pytest.approx(0.3)
    cov = np.asarray(first.pose.covariance).reshape(6, 6)
    small = np.array(COV).reshape(3, 3)
    np.testing.assert_array_equal(cov[np.ix_([0, 1, 5], [0, 1, 5])], small)
    assert cov[2, 2] == cov[3, 3] == cov[4, 4] >= 1e6, "z, roll, pitch unmeasured"
    assert first.header.stamp.sec * 10**9 + first.header.stamp.nanosec == T0 + 33_000_000
    no_yaw = np.asarray(poses[1][2].pose.covariance).reshape(6, 6)
    assert no_yaw[5, 5] >= 1e6 and no_yaw[0, 0] >= 1e6, "no covariance given: nothing claimed as measured"
    tf = [t for _, _, m in found["/tf"] for t in m.transforms]
    assert [(t.header.frame_id, t.child_frame_id) for t in tf][:2] == [("court", "base_link"), ("base_link", "camera")]
    static = found["/tf_static"][0][2].transforms[0]
    assert (static.header.frame_id, static.child_frame_id) == ("base_link", "camera")
    images = found["/courtloc/camera/image/compressed"]
    assert [m[2].format for m in images] == ["jpeg", "jpeg"]
    assert bytes(images[0][2].data) == _jpeg(), "a JPEG frame is passed through unchanged"
    import cv2

    decoded = cv2.imdecode(np.asarray(images[1][2].data, np.uint8), cv2.IMREAD_COLOR)
    assert decoded.shape == (2, 4, 3), "a raw frame becomes a JPEG of the same size"
    shots = [m[2] for m in found["/courtloc/shot_solution"]]
    assert [(s.command, s.valid, s.rpm) for s in shots] == [("SET_RPM", True, 2300.0), ("HOLD", False, 0.0)]
    assert math.isnan(shots[1].distance_m) and math.isnan(shots[1].bearing_rad)
    assert found["/courtloc/shot_solution"][0][0] == types.SHOT


def test_export_refuses_an_existing_folder_in_one_line(recording: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["export", "rosbag2", str(recording), str(tmp_path)])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "exists" in err
    with pytest.raises(SystemExit) as exit_info:
        main(["export", "rosbag2", str(tmp_path / "missing.mcap"), str(tmp_path / "new")])
    assert exit_info.value.code == 2 and "no recording" in capsys.readouterr().err


@pytest.mark.parametrize("args, field", [(["--domain", "999"], "domain_id"),
                                         (["--odometry-topic", "/bad topic"], "odometry_topic")])
def test_bridge_options_fail_at_start_naming_the_field(args: list[str], field: str,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["ros", "bridge", "--connect", "tcp/127.0.0.1:1", *args])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and len(err.splitlines()) == 1 and field in err

"""Recordings as Foxglove reads them: every JSON message valid against the schema stored with its channel,
poses / TF / court / hits as the official Foxglove types, the exact payloads in their own file."""
from __future__ import annotations

import base64
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from courtloc.common import codec
from courtloc.common.messages import Edges, Frame, GroundTruth, Header, Health, Odometry, Pose, ShotSolution, StageStamp
from courtloc.common.services_table import TOPICS
from courtloc.foxglove.scene import matrix_quaternion
from courtloc.recording.foxview import FoxgloveViews
from courtloc.recording.mcapfile import VIEW_FOXGLOVE, VIEW_MSGPACK, Limits, McapSeries, exact_path, read_series
from courtloc.recording.recorder import record_item

jsonschema = pytest.importorskip("jsonschema", reason="the test extra's JSON-schema validator")

ROBOT = "robot1"
T0 = 1_700_000_000_000_000_000


def _header(seq: int, stage: str, valid: bool = True) -> Header:
    wall = T0 + seq * 33_000_000
    return Header(robot_id=ROBOT, seq=seq, capture_mono_ns=seq, capture_wall_ns=wall, capture_host="robot",
                  valid=valid, stamps=[StageStamp(stage=stage, mono_ns=seq + 1, wall_ns=wall + 1, host="robot")])


def every_kind_of_message() -> list[tuple[str, Any]]:
    """At least one message per topic of the services table, with the values that break naive JSON:
    NaN and infinite floats, missing yaw and bearing, invalid poses, raw and JPEG frames."""
    hits = np.array([[100, 200, 0, 5], [120, 220, 1, 6], [300, 10, 2, 7]], "<i2")
    health = dict(uptime_s=1.0, rate_in_hz=30.0, rate_out_hz=29.5, frames_in=30, frames_out=29, dropped=1, rejected=0,
                  stale=0, latency_ms_p50=1.5, latency_ms_p99=float("nan"))
    messages: list[tuple[str, Any]] = [
        ("camera/frame", Frame(header=_header(1, "camera"), width=4, height=2, encoding="bgr8", data=bytes(24))),
        ("preprocess/preview", Frame(header=_header(1, "preprocess"), width=4, height=2, encoding="jpeg",
                                     data=b"\xff\xd8\xff\xe0 jpeg")),
        ("camera/ground_truth", GroundTruth(header=_header(1, "camera"), x=1.0, y=-2.0, yaw=0.5, source="sim")),
        ("preprocess/edges", Edges(header=_header(1, "preprocess"), width=640, height=480, crop_top=0, n_hits=3,
                                   hits=hits.tobytes())),
        ("infer/pose", Pose(header=_header(1, "infer"), x=1.01, y=-1.98, yaw=0.51, quality=0.9, model_name="m",
                            model_version=2, infer_ms=0.8)),
        ("infer/pose", Pose(header=_header(2, "infer", valid=False), x=float("nan"), y=float("nan"), yaw=None,
                            model_name="m", model_version=2, infer_ms=0.8, reason="degenerate")),
        ("infer/pose", Pose(header=_header(3, "infer"), x=2.0, y=0.5, yaw=None, model_name="xy", model_version=1,
                            infer_ms=float("inf"))),
        ("infer/shadow_pose", Pose(header=_header(1, "infer"), x=1.0, y=-2.0, yaw=0.4, model_name="m2",
                                   model_version=3, infer_ms=1.0)),
        ("shooter_bridge/solution", ShotSolution(header=_header(1, "shooter_bridge", valid=True), distance_m=4.2,
                                                 bearing_rad=0.1, rpm=2300.0, command="SET_RPM")),
        ("shooter_bridge/solution", ShotSolution(header=_header(2, "shooter_bridge", valid=False),
                                                 distance_m=float("nan"), bearing_rad=None, rpm=0.0, command="HOLD",
                                                 reason="no_pose")),
        ("shooter_bridge/odometry", Odometry(header=_header(1, "shooter_bridge"), source="mcu", source_seq=1,
                                             source_time_ns=5, received_mono_ns=6, window_s=0.01, vx_m_s=0.5,
                                             wz_gyro_rad_s=float("nan"), wheels_valid=True)),
    ]
    for service in ("camera", "preprocess", "infer", "shooter_bridge"):
        detail: dict[str, float | int | str] = {"k": float("nan"), "n": 3, "s": "x"}
        messages.append((f"{service}/health", Health(robot_id=ROBOT, service=service, pid=1, wall_ns=T0,
                                                     detail=detail, **health)))
    assert {path for path, _ in messages} == set(TOPICS), "one message per topic of the services table"
    return messages


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fox") / "match.mcap"
    series = McapSeries(out, Limits(), {"robot_id": ROBOT}, FoxgloveViews.load("seed-gazebo"))
    for i, (path, message) in enumerate(every_kind_of_message()):
        series.write(record_item(path, ROBOT, codec.encode(message), T0 + i * 1_000_000, series.foxglove))
    series.close()
    return out


def _read(file: Path) -> list[tuple[Any, Any, Any]]:
    with file.open("rb") as handle:
        return list(make_reader(handle, validate_crcs=True).iter_messages(log_time_order=True))


def test_every_json_message_validates_against_its_stored_schema(recording: Path) -> None:
    validated: dict[str, int] = {}
    for schema, channel, message in _read(recording):
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema", channel.topic
        schema_json = json.loads(schema.data)
        jsonschema.Draft202012Validator.check_schema(schema_json)
        validator = jsonschema.Draft202012Validator(schema_json, format_checker=jsonschema.FormatChecker())
        errors = [e.message for e in validator.iter_errors(json.loads(message.data))]
        assert not errors, (channel.topic, errors)
        validated[schema.name] = validated.get(schema.name, 0) + 1
    assert validated["courtloc.ShotSolution"] == 2, "the HOLD with distance NaN (null) included"
    for name in ("courtloc.Pose", "courtloc.Health", "courtloc.Edges", "courtloc.GroundTruth", "foxglove.RawImage",
                 "foxglove.CompressedImage", "foxglove.PoseInFrame", "foxglove.FrameTransform",
                 "foxglove.SceneUpdate", "foxglove.ImageAnnotations"):
        assert validated.get(name), name


def test_a_null_distance_is_refused_by_the_old_schema_and_allowed_by_the_new(recording: Path) -> None:
    hold = next(json.loads(m.data) for s, c, m in _read(recording)
                if s.name == "courtloc.ShotSolution" and json.loads(m.data)["command"] == "HOLD")
    assert hold["distance_m"] is None
    strict = ShotSolution.model_json_schema(mode="serialization")  # pydantic's, as stored before
    assert list(jsonschema.Draft202012Validator(strict).iter_errors(hold)), "the view needs the nullable schema"


def test_exact_payloads_live_in_their_own_file(recording: Path) -> None:
    view_channels = {c.topic for _, c, _ in _read(recording)}
    assert not any(c.endswith("#msgpack") for c in view_channels)
    exact = _read(exact_path(recording))
    assert {c.message_encoding for _, c, _ in exact} == {VIEW_MSGPACK}
    sent = [codec.encode(m) for _, m in every_kind_of_message()]
    replayed = [r.data for r in read_series([recording])]
    assert len(replayed) == len(sent)
    for got, (path, message) in zip(replayed, every_kind_of_message()):
        decoded = codec.decode(got, type(message))
        assert got == codec.encode(message), path
        assert repr(decoded) == repr(message), path  # NaN kept


def test_poses_tf_court_and_hits_as_foxglove_types(recording: Path) -> None:
    by_topic: dict[str, list[tuple[Any, Any, dict[str, Any]]]] = {}
    for schema, channel, message in _read(recording):
        by_topic.setdefault(channel.topic, []).append((schema, channel, json.loads(message.data)))
    poses = by_topic[f"courtloc/{ROBOT}/infer/pose/in_frame"]
    assert [p[2]["pose"]["position"]["x"] for p in poses] == [1.01, 2.0], "the NaN pose has no PoseInFrame"
    assert poses[0][1].metadata["courtloc.view"] == VIEW_FOXGLOVE
    yaw = 2 * math.atan2(poses[0][2]["pose"]["orientation"]["z"], poses[0][2]["pose"]["orientation"]["w"])
    assert yaw == pytest.approx(0.51, abs=1e-12)
    tf = [m for _, _, m in by_topic[f"courtloc/{ROBOT}/tf"]]
    robot = [t for t in tf if t["child_frame_id"] == "base_link"]
    assert [(t["translation"]["x"], t["parent_frame_id"]) for t in robot] == [(1.01, "court"), (2.0, "court")], \
        "TF only from valid poses"
    camera = [t for t in tf if t["child_frame_id"] == "camera"]
    assert camera and all(t["parent_frame_id"] == "base_link" for t in camera)
    scene = by_topic[f"courtloc/{ROBOT}/scene"]
    assert len(scene) == 1
    entities = {e["id"]: e for e in scene[0][2]["entities"]}
    assert entities["court"]["frame_id"] == "court" and len(entities["court"]["lines"]) > 10
    assert entities["robot"]["frame_id"] == "base_link" and entities["robot"]["cubes"]
    hits = by_topic[f"courtloc/{ROBOT}/preprocess/edges/annotations"][0][2]
    assert [(p["x"], p["y"]) for p in hits["points"][0]["points"]] == [(200.5, 100.5), (220.5, 120.5), (10.5, 300.5)]
    frame = by_topic[f"courtloc/{ROBOT}/camera/frame"][0][2]
    assert base64.b64decode(frame["data"]) == bytes(24)


def test_camera_transform_is_the_camera_models_rotation() -> None:
    from courtloc.world.camera import load_camera

    camera = load_camera("seed-gazebo")
    q = matrix_quaternion(camera.robot_from_camera_rotation())
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    rebuilt = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(rebuilt, camera.robot_from_camera_rotation(), atol=1e-12)
    # the optical axis (camera +z) points forward and down on a robot camera tilted to the floor
    forward = rebuilt @ np.array([0.0, 0.0, 1.0])
    assert forward[0] > 0 and forward[2] <= 0


def _to_sdk(value: Any, schema: dict[str, Any], messages: Any, owner: str = "", field: str = "") -> Any:
    """A JSON message as the official foxglove-sdk message class (unknown fields or types raise)."""
    enums = {("foxglove.LinePrimitive", "type"): messages.LinePrimitiveLineType,
             ("foxglove.SceneEntityDeletion", "type"): messages.SceneEntityDeletionType,
             ("foxglove.PointsAnnotation", "type"): messages.PointsAnnotationType}
    if schema.get("type") == "object":
        title = schema["title"]
        cls = {"time": messages.Timestamp, "duration": messages.Duration}.get(title) or \
            getattr(messages, title.split(".", 1)[1])
        return cls(**{k: _to_sdk(v, schema["properties"][k], messages, title, k) for k, v in value.items()})
    if schema.get("type") == "array":
        return [_to_sdk(v, schema["items"], messages, owner, field) for v in value]
    if (owner, field) in enums:
        enum = enums[(owner, field)]
        return next(getattr(enum, n) for n in dir(enum) if not n.startswith("_") and n not in ("name", "value")
                    and getattr(enum, n).value == value)
    if schema.get("contentEncoding") == "base64":
        return base64.b64decode(value)
    return value


def test_foxglove_channels_are_accepted_by_the_official_sdk_classes(recording: Path) -> None:
    messages = pytest.importorskip("foxglove.messages", reason="foxglove-sdk (the foxglove extra)")
    checked = 0
    for schema, _, message in _read(recording):
        if schema.name.startswith("foxglove."):
            sdk = _to_sdk(json.loads(message.data), json.loads(schema.data), messages)
            assert type(sdk).__name__ == schema.name.split(".", 1)[1] and sdk.encode()
            checked += 1
    assert checked >= 8


def _layout_topics(node: object) -> set[str]:
    """Every topic a Foxglove layout names: topic keys, image and annotation topics, message paths."""
    found: set[str] = set()
    if isinstance(node, dict):
        for key, value in node.items():
            if isinstance(key, str) and key.startswith("courtloc/"):
                found.add(key)
            found |= _layout_topics(value)
    elif isinstance(node, list):
        for value in node:
            found |= _layout_topics(value)
    elif isinstance(node, str) and "courtloc/" in node:
        found.add(node.split('"')[1] if node.startswith('"') else node)
    return found


def test_the_shipped_layout_names_only_topics_a_recording_has(recording: Path) -> None:
    layout = json.loads((Path(__file__).resolve().parents[1] / "deploy" / "foxglove" / "courtloc.json").read_text())
    assert set(layout["configById"]) >= {"3D!court", "Image!camera"}
    named = _layout_topics(layout["configById"])
    recorded = {c.topic for _, c, _ in _read(recording)}
    assert named and named <= recorded, named - recorded
    assert layout["configById"]["3D!court"]["followTf"] == "court"

"""Every message is bounded and checked strictly at the wire; refusals are counted with a reason.

Limits live in common/limits.py; the message models enforce them per field and the services table
derives each topic's largest payload from them.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import msgpack
import numpy as np
import pytest
import zenoh
from buskit import BusClient, free_port, start_router, start_stage, write_config

from courtloc.common import codec
from courtloc.common.control import ModelRequest, PushChunk
from courtloc.common.limits import (
    MAX_CHUNK_BYTES,
    MAX_HITS,
    MAX_IMAGE_BYTES,
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    MAX_NAME_CHARS,
    MAX_STAMPS,
    MAX_TEXT_CHARS,
)
from courtloc.common.messages import Edges, Frame, Header, Pose, StageStamp
from courtloc.common.services_table import CONTROLS, TOPICS


def _header(**changes: object) -> dict:
    return {**Header.now("robot1", 1, "test").model_dump(), **changes}


def _pose(**header_changes: object) -> dict:
    return {"header": _header(**header_changes), "x": 1.0, "y": 2.0, "yaw": 0.0, "quality": 1.0,
            "model_name": "m", "model_version": 1, "infer_ms": 0.1, "reason": ""}


def _reason(payload: bytes, message_type: type, max_bytes: int | None = None) -> str:
    with pytest.raises(codec.DecodeError) as caught:
        codec.decode(payload, message_type, max_bytes)
    return caught.value.reason


@pytest.mark.parametrize("field, value", [
    ("valid", "yes"), ("valid", 1), ("seq", "640"), ("seq", 1.0), ("capture_mono_ns", "123"),
])
def test_header_fields_are_checked_not_coerced(field: str, value: object) -> None:
    assert _reason(msgpack.packb(_pose(**{field: value})), Pose) == "invalid"


def test_frame_size_as_text_is_refused() -> None:
    frame = {"header": _header(), "width": "640", "height": 480, "encoding": "bgr8", "data": b"\0" * 10}
    assert _reason(msgpack.packb(frame, use_bin_type=True), Frame) == "invalid"


def test_a_valid_message_still_round_trips() -> None:
    pose = Pose.model_validate(_pose(valid=True))
    assert codec.decode(codec.encode(pose), Pose) == pose


@pytest.mark.parametrize("payload", [
    pytest.param(_pose(stamps=[StageStamp(stage="s", mono_ns=0, wall_ns=0).model_dump()] * (MAX_STAMPS + 1)),
                 id="stamps"),
    pytest.param(_pose(robot_id="r" * (MAX_NAME_CHARS + 1)), id="robot_id"),
    pytest.param({**_pose(), "reason": "x" * (MAX_TEXT_CHARS + 1)}, id="reason"),
    pytest.param({**_pose(), "model_name": "m" * 10_000}, id="model_name"),
])
def test_string_and_list_lengths_are_bounded(payload: dict) -> None:
    assert _reason(msgpack.packb(payload, use_bin_type=True), Pose) == "invalid"


@pytest.mark.parametrize("width, height", [(16000, 16000), (MAX_IMAGE_SIDE + 1, 1), (MAX_IMAGE_SIDE, MAX_IMAGE_SIDE)])
def test_declared_image_size_is_bounded(width: int, height: int) -> None:
    frame = {"header": _header(), "width": width, "height": height, "encoding": "jpeg", "data": b"\xff\xd8"}
    assert _reason(msgpack.packb(frame, use_bin_type=True), Frame) == "invalid"
    edges = {"header": _header(), "width": width, "height": height, "crop_top": 0, "n_hits": 0, "hits": b""}
    assert _reason(msgpack.packb(edges, use_bin_type=True), Edges) == "invalid"


def test_hit_count_is_bounded() -> None:
    edges = {"header": _header(), "width": 640, "height": 480, "crop_top": 0, "n_hits": MAX_HITS + 1,
             "hits": b"\0" * 8}
    assert _reason(msgpack.packb(edges, use_bin_type=True), Edges) == "invalid"


def test_payload_bigger_than_the_topic_allows_is_refused_before_unpacking() -> None:
    topic = TOPICS["infer/pose"]
    assert _reason(b"\x00" * (topic.max_bytes + 1), Pose, topic.max_bytes) == "too_large"


def test_topic_limits_are_derived_from_the_contract() -> None:
    """The largest legal message of each bulk topic fits its limit; the limit is not much more."""
    side = int(MAX_IMAGE_PIXELS ** 0.5)
    biggest_frame = Frame(header=Header(robot_id="r" * MAX_NAME_CHARS, seq=0, capture_mono_ns=0, capture_wall_ns=0,
                                        capture_host="h" * 255,
                                        stamps=[StageStamp(stage="s" * MAX_NAME_CHARS, mono_ns=0, wall_ns=0,
                                                           host="h" * 255)] * MAX_STAMPS),
                          width=side, height=side, encoding="bgr8", data=b"\0" * MAX_IMAGE_BYTES)
    encoded = len(codec.encode(biggest_frame))
    assert encoded <= TOPICS["camera/frame"].max_bytes < 2 * encoded
    assert TOPICS["preprocess/edges"].max_bytes >= MAX_HITS * 8
    assert TOPICS["infer/pose"].max_bytes < TOPICS["preprocess/edges"].max_bytes
    chunk = ModelRequest(body=PushChunk(upload_id="u" * MAX_NAME_CHARS, file_index=0, offset=0,
                                        data=b"\0" * MAX_CHUNK_BYTES))
    assert len(codec.encode(chunk)) <= CONTROLS["infer/model"].max_bytes
    too_big = {"body": {"op": "push_chunk", "upload_id": "u", "file_index": 0, "offset": 0,
                        "data": b"\0" * (MAX_CHUNK_BYTES + 1)}, "schema_version": 1}
    assert _reason(msgpack.packb(too_big, use_bin_type=True), ModelRequest) == "invalid"


def _jpeg(width: int = 640, height: int = 480) -> bytes:
    ok, data = cv2.imencode(".jpg", np.zeros((height, width, 3), np.uint8))
    assert ok
    return data.tobytes()


def _frame_payload(**fields: object) -> bytes:
    frame = {"header": _header(valid=True), "width": 640, "height": 480, "encoding": "jpeg", "data": _jpeg(), **fields}
    return msgpack.packb(frame, use_bin_type=True)


@pytest.mark.integration
def test_preprocess_process_counts_every_hostile_frame_by_reason_and_keeps_working(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    config = write_config(tmp_path / "deploy.toml", port, health_period_s=0.2)  # each step waits for a report
    client = BusClient(port)
    client.subscribe("preprocess/health")
    client.subscribe("preprocess/edges")
    stage = start_stage("preprocess", config)
    sof = _jpeg(8, 8).index(b"\xff\xc0")
    small = _jpeg(8, 8)
    bomb = small[:sof + 5] + (16000).to_bytes(2, "big") * 2 + small[sof + 9:]
    ok, png = cv2.imencode(".png", np.zeros((480, 640, 3), np.uint8))
    hostile = [
        ("too_large", b"\x00" * (TOPICS["camera/frame"].max_bytes + 1)),
        ("invalid", _frame_payload(width="640")),  # coerced before: a text size
        ("invalid", _frame_payload(header=_header(stamps=[{"stage": "s", "mono_ns": 0, "wall_ns": 0,
                                                           "host": "h"}] * 1000))),
        ("invalid", _frame_payload(width=16000, height=16000)),
        ("size", _frame_payload(data=bomb)),  # 640x480 claimed, 16000x16000 inside
        ("not_jpeg", _frame_payload(data=png.tobytes())),
    ]
    try:
        client.wait_alive("preprocess")
        client.wait_subscribed("camera/frame")
        # Counts so far, from a health report sent after the stage started; then one payload at a time (the
        # inbox is bounded), each counted under its reason before the next is sent.
        counted = client.wait_for("preprocess/health").detail
        expected = {f"reject.{r}": counted.get(f"reject.{r}", 0) for r, _ in hostile}
        for reason, payload in hostile:
            expected[f"reject.{reason}"] += 1
            # BLOCK: a multi-megabyte payload must not be dropped in transit on a busy machine
            client.session.put(TOPICS["camera/frame"].key("robot1"), payload,
                               congestion_control=zenoh.CongestionControl.BLOCK)
            client.wait_for("preprocess/health", lambda h, want=dict(expected): all(
                h.detail.get(key, 0) >= count for key, count in want.items()))
        client.put_raw("camera/frame", _frame_payload())
        edges = client.wait_for("preprocess/edges")
        assert edges.header.valid and edges.width == 640
        assert stage.alive()
        health = client.wait_for("preprocess/health")
        assert health.rejected >= len(hostile) and len(health.last_error) <= MAX_TEXT_CHARS
    finally:
        client.close()
        stage.stop()
        router.stop()
    assert "Traceback" not in stage.output()


@pytest.mark.integration
def test_handler_exceptions_are_counted_and_logged_rate_limited(tmp_path: Path) -> None:
    """Edges of a frame size the model cannot take make the handler raise: each one is a rejection with
    a reason, and the log gets one traceback, not one per message."""
    from infer_models import TwinFrames

    frames = TwinFrames([(2.0, -1.5, 0.4)])
    port = free_port()
    router = start_router(port)
    config = write_config(tmp_path / "deploy.toml", port, f'[infer]\nstore = "{tmp_path / "store"}"\n',
                          health_period_s=0.2)
    client = BusClient(port)
    client.subscribe("infer/health")
    stage = start_stage("infer", config)
    n = 300
    try:
        stage.wait_line("infer running for robot", timeout=60)
        client.wait_subscribed("preprocess/edges")
        good = frames.edges(0, 1)
        for seq in range(n):
            bad = good.model_copy(update={"header": good.header.model_copy(update={"seq": seq}),
                                          "width": 1, "height": 1, "crop_top": 0})
            client.put_raw("preprocess/edges", codec.encode(bad))
        # bounded inbox: each one was either taken (and must be rejected) or pushed out (dropped)
        health = client.wait_for("infer/health", lambda h: h.frames_in + h.dropped >= n)
        assert health.detail.get("reject.handler_error", 0) == health.rejected == health.frames_in >= 1
        assert stage.alive()
    finally:
        client.close()
        stage.stop()
        router.stop()
    assert stage.output().count("Traceback") == 1, stage.output()[-3000:]

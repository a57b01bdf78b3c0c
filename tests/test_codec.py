import msgpack
import pytest

from courtloc.common import codec
from courtloc.common.messages import SCHEMA_VERSION, Edges, Frame, Header, Health, Pose
from courtloc.common.services_table import TOPICS


def _frame() -> Frame:
    header = Header.now("robot1", 7, "camera")
    return Frame(header=header, width=4, height=2, encoding="bgr8", data=bytes(range(24)))


def test_round_trip_keeps_every_field() -> None:
    frame = _frame()
    back = codec.decode(codec.encode(frame), Frame)
    assert back == frame
    assert back.header.valid is False  # nobody set it


def test_valid_defaults_to_false_and_stamps_accumulate() -> None:
    header = Header.now("robot1", 0, "camera")
    assert header.valid is False
    later = header.forwarded("preprocess", valid=True)
    assert later.valid and not header.valid
    assert [s.stage for s in later.stamps] == ["camera", "preprocess"]
    assert later.span_ns() >= 0


@pytest.mark.parametrize("cut", [1, 10, 40])
def test_truncated_payload_is_rejected_with_reason(cut: int) -> None:
    payload = codec.encode(_frame())
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(payload[:cut], Frame)
    assert info.value.reason in {"truncated", "not_msgpack"}


def test_unknown_schema_version_is_rejected() -> None:
    raw = _frame().model_dump()
    raw["header"]["schema_version"] = SCHEMA_VERSION + 1
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(raw), Frame)
    assert info.value.reason == "schema_version"


def test_wrong_type_names_the_field() -> None:
    raw = _frame().model_dump()
    raw["width"] = "wide"
    with pytest.raises(codec.DecodeError) as info:
        codec.decode(msgpack.packb(raw), Frame)
    assert info.value.reason == "invalid"
    assert "width" in info.value.detail


@pytest.mark.parametrize("payload", [b"", b"\xc1", msgpack.packb([1, 2, 3]), msgpack.packb("x" * 5)])
def test_garbage_never_raises_anything_but_decode_error(payload: bytes) -> None:
    for topic in TOPICS.values():
        with pytest.raises(codec.DecodeError):
            codec.decode(payload, topic.message)


def test_message_of_another_type_is_rejected() -> None:
    pose = Pose(header=Header.now("r", 1, "infer"), x=1, y=2, model_name="m", model_version=1, infer_ms=0.1)
    with pytest.raises(codec.DecodeError):
        codec.decode(codec.encode(pose), Edges)


def test_health_round_trip() -> None:
    health = Health(robot_id="r", service="camera", uptime_s=1.0, rate_in_hz=0, rate_out_hz=30, frames_in=0,
                    frames_out=30, dropped=0, rejected=0, stale=0, latency_ms_p50=1, latency_ms_p99=2)
    assert codec.decode(codec.encode(health), Health) == health

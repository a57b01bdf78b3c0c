"""`courtloc record`: MCAP files that standard readers accept, a JSON view, exact payloads, rotation."""
from __future__ import annotations

import base64
import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router
from mcap.reader import make_reader

from courtloc.common import codec
from courtloc.common.messages import Frame, Header, Health, Pose
from courtloc.common.services_table import TOPICS
from courtloc.recording.jsonview import json_view, schema_data
from courtloc.recording.mcapfile import VIEW_JSON, Limits, McapSeries, RecordItem, exact_path, read_series, series_files
from courtloc.recording.recorder import resolve_topics

ROBOT = "robot1"


def _pose(seq: int, x: float = 1.0) -> Pose:
    header = Header.now(ROBOT, seq, "infer")
    header.valid = True
    return Pose(header=header, x=x, y=-2.0, yaw=0.3, model_name="m", model_version=2, infer_ms=1.0)


def _frame(seq: int, size: int = 20_000) -> Frame:
    data = np.random.default_rng(seq).bytes(size)  # incompressible: files fill at their raw size
    return Frame(header=Header.now(ROBOT, seq, "camera"), width=size // 3 // 10, height=10, encoding="bgr8",
                 data=data[: (size // 3 // 10) * 10 * 3])


def _item(path: str, message, log_time: int) -> RecordItem:  # noqa: ANN001
    return RecordItem(path=path, robot_id=ROBOT, log_time=log_time, publish_time=log_time,
                      sequence=message.header.seq, raw=codec.encode(message),
                      json=json_view(message, TOPICS[path].service))


def test_rotation_by_size_keeps_every_file_valid_and_under_the_limit(tmp_path: Path) -> None:
    out = tmp_path / "run.mcap"
    limit = 200_000
    series = McapSeries(out, Limits(max_bytes=limit), {"robot_id": ROBOT})
    sent = [_frame(i) for i in range(40)]
    for i, frame in enumerate(sent):
        series.write(_item("camera/frame", frame, 1_000_000_000 + i * 33_000_000))
    series.close()
    files = series_files(out)
    assert files == series.files and [f.name for f in files][:2] == ["run-000.mcap", "run-001.mcap"]
    assert len(files) >= 4, "40 frames of ~2x20 kB cannot fit in fewer 200 kB files"
    for file in files:
        assert file.stat().st_size <= limit, f"{file.name} is {file.stat().st_size} bytes"
        with file.open("rb") as handle:  # CRCs checked: what any MCAP reader would verify
            assert sum(1 for _ in make_reader(handle, validate_crcs=True).iter_messages()) > 0
    replayed = [r.data for r in read_series(files)]
    assert replayed == [codec.encode(f) for f in sent], "every payload, exact and in order, across the parts"


def test_rotation_by_duration_uses_log_time(tmp_path: Path) -> None:
    out = tmp_path / "timed.mcap"
    series = McapSeries(out, Limits(max_seconds=1.0), {})
    for i in range(25):  # 2.4 s of poses at 10 Hz
        series.write(_item("infer/pose", _pose(i), 5_000_000_000 + i * 100_000_000))
    series.close()
    counts = [sum(1 for _ in read_series([f])) for f in series_files(out)]
    assert counts == [10, 10, 5]


def test_json_view_is_foxglove_json_with_schema(tmp_path: Path) -> None:
    out = tmp_path / "view.mcap"
    series = McapSeries(out, Limits(), {})
    frame = _frame(3, 300)
    jpeg = Frame(header=Header.now(ROBOT, 4, "preprocess"), width=2, height=2, encoding="jpeg", data=b"\xff\xd8fake")
    pose = _pose(4, x=float("nan"))
    series.write(_item("camera/frame", frame, 1))
    series.write(_item("preprocess/preview", jpeg, 2))
    series.write(_item("infer/pose", pose, 3))
    series.close()
    with out.open("rb") as handle:
        reader = make_reader(handle, validate_crcs=True)
        views = {channel.topic: (schema, channel, message)
                 for schema, channel, message in reader.iter_messages() if channel.message_encoding == VIEW_JSON}
    # A pose: the courtloc schema (pydantic's), NaN as null; the msgpack channel keeps the NaN.
    schema, channel, message = views[TOPICS["infer/pose"].key(ROBOT)]
    assert schema.encoding == "jsonschema" and schema.name == "courtloc.Pose"
    assert json.loads(schema.data)["properties"]["model_version"]["type"] == "integer"
    body = json.loads(message.data)
    assert body["x"] is None and body["header"]["seq"] == 4 and channel.metadata["courtloc.path"] == "infer/pose"
    kept = codec.decode(next(r for r in read_series([out]) if r.path == "infer/pose").data, Pose)
    assert math.isnan(kept.x)
    # Frames: Foxglove's image messages, binary as standard base64 (not URL-safe) flagged in the schema.
    schema, _, message = views[TOPICS["camera/frame"].key(ROBOT)]
    assert schema.name == "foxglove.RawImage"
    assert json.loads(schema.data)["properties"]["data"]["contentEncoding"] == "base64"
    image = json.loads(message.data)
    assert base64.b64decode(image["data"]) == frame.data and image["encoding"] == "bgr8"
    assert (image["width"], image["height"], image["step"]) == (frame.width, frame.height, frame.width * 3)
    assert image["timestamp"]["sec"] * 10**9 + image["timestamp"]["nsec"] == frame.header.capture_wall_ns
    schema, _, message = views[TOPICS["preprocess/preview"].key(ROBOT)]
    assert schema.name == "foxglove.CompressedImage"
    assert json.loads(message.data)["format"] == "jpeg" and json.loads(message.data)["frame_id"] == "preprocess"
    raw_frame = next(r for r in read_series([out]) if r.path == "camera/frame")
    assert codec.decode(raw_frame.data, Frame) == frame, "the full Frame, header included, on the msgpack channel"


def test_courtloc_schemas_mark_binary_fields_base64() -> None:
    edges = json.loads(schema_data("courtloc.Edges"))
    assert edges["properties"]["hits"] == {"contentEncoding": "base64", "title": "Hits", "type": "string"}
    assert "$defs" in edges and edges["$defs"]["Header"]["properties"]["seq"]["type"] == "integer"


def test_topic_selection() -> None:
    assert "camera/frame" not in resolve_topics(None) and "infer/pose" in resolve_topics(None)
    assert "camera/frame" in resolve_topics(["all"])
    assert resolve_topics(["infer/pose", "infer/pose"]) == ["infer/pose"]
    with pytest.raises(ValueError, match="infer/posse"):
        resolve_topics(["infer/posse"])


@pytest.mark.integration
def test_record_command_keeps_bad_payloads_and_skips_frames_by_default(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    out = tmp_path / "bus.mcap"
    recorder = Proc([*PYTHON, "record", str(out), "--connect", endpoint(port), "--robot", ROBOT,
                     "--max-messages", "12"]).start()
    client = BusClient(port)
    try:
        recorder.wait_line("recording")
        # The recorder's subscriptions reach the router after it says it records: a put before reaches nobody.
        client.wait_subscribed("infer/pose")
        client.wait_subscribed("infer/health")
        client.put_raw("camera/frame", codec.encode(_frame(0, 300)))  # not selected by default
        for seq in range(10):
            client.put_raw("infer/pose", codec.encode(_pose(seq, x=0.5 * seq)))
        client.put_raw("infer/pose", b"\xc1 not msgpack")
        client.put_raw("infer/health", codec.encode(Health(
            robot_id=ROBOT, service="infer", uptime_s=1, rate_in_hz=1, rate_out_hz=1, frames_in=1, frames_out=1,
            dropped=0, rejected=0, stale=0, latency_ms_p50=1, latency_ms_p99=2)))
        assert recorder.process is not None and recorder.process.wait(30) == 0, recorder.output()
    finally:
        client.close()
        recorder.stop()
        router.stop()
    summary = json.loads(recorder.lines[-1])
    assert summary["messages"] == {"infer/pose": 11, "infer/health": 1}
    assert summary["undecodable"] == {"infer/pose": 1}
    records = list(read_series([out]))
    poses = [r.data for r in records if r.path == "infer/pose"]
    assert poses[-1] == b"\xc1 not msgpack", "a payload that does not decode is kept, byte for byte"
    assert [codec.decode(p, Pose).x for p in poses[:-1]] == [0.5 * s for s in range(10)]
    assert not any(r.path == "camera/frame" for r in records)
    assert sum(1 for _ in read_series([out], view=VIEW_JSON)) == 11, "JSON views of the 11 decodable messages"
    jsonschema = pytest.importorskip("jsonschema", reason="the test extra's JSON-schema validator")
    with out.open("rb") as handle:  # what `courtloc record` wrote: every message valid against its stored schema
        checked = 0
        for schema, channel, message in make_reader(handle, validate_crcs=True).iter_messages():
            validator = jsonschema.Draft202012Validator(json.loads(schema.data))
            errors = list(validator.iter_errors(json.loads(message.data)))
            assert not errors, (channel.topic, errors[0].message)
            checked += 1
    assert checked > 11, "the JSON views plus the Foxglove channels (scene, poses in frame, TF)"


def test_a_recording_cut_short_is_readable_up_to_the_last_flush(tmp_path: Path) -> None:
    """A recorder killed hard (power, SIGKILL) leaves no index; the chunks it closed are still replayable."""
    out = tmp_path / "cut.mcap"
    series = McapSeries(out, Limits(), {})
    for seq in range(5):
        series.write(_item("infer/pose", _pose(seq, x=float(seq)), 1_000 + seq))
    series.tick(now=time.monotonic() + 2.0)  # a second passed: the open chunk is closed and written
    series.write(_item("infer/pose", _pose(5), 2_000))  # still in the open chunk when the "power" goes
    cut = tmp_path / "copy.mcap"
    cut.write_bytes(out.read_bytes())  # the files as the disk holds them now: no summary, no footer
    exact_path(cut).write_bytes(exact_path(out).read_bytes())
    series.close()
    recovered = [codec.decode(r.data, Pose).x for r in read_series([cut])]
    assert recovered == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert len(list(read_series([out]))) == 6, "the finished file has everything"


def test_replay_without_the_exact_file_says_which_file_is_missing(tmp_path: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from courtloc.cli import main

    out = tmp_path / "view.mcap"
    series = McapSeries(out, Limits(), {})
    series.write(_item("infer/pose", _pose(1), 1_000))
    series.close()
    exact_path(out).unlink()  # copied without its twin
    with pytest.raises(SystemExit) as exit_info:
        main(["replay", str(out), "--connect", "tcp/127.0.0.1:1"])
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 2 and len(err.splitlines()) == 1 and "view.exact.mcap" in err

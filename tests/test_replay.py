"""Process replay: a recorded live run, replayed through a fresh stage, must give the recorded outputs."""
from __future__ import annotations

import json
import queue
import time
from pathlib import Path

import pytest

from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router, start_stage, write_config
from courtloc.common import codec
from courtloc.common.messages import Edges, Frame, Header, Pose
from courtloc.common.services_table import TOPICS
from courtloc.recording.jsonview import json_view
from courtloc.recording.mcapfile import Limits, McapSeries, RecordItem, read_series
from courtloc.recording.replay import Recorded, rewrite

pytestmark = pytest.mark.integration
ROBOT = "robot1"


def _edges_key(edges: Edges) -> tuple[int, int, int, int, bytes]:
    """Everything preprocess computes from the pixels (the header differs: stamps, freshness)."""
    return edges.width, edges.height, edges.crop_top, edges.n_hits, edges.hits


def _record_live_run(tmp_path: Path, port: int, config: Path, out: Path, n_edges: int) -> None:
    client = BusClient(port)
    client.subscribe("preprocess/edges")
    recorder = Proc([*PYTHON, "record", str(out), "--topics", "camera/frame", "preprocess/edges",
                     "--connect", endpoint(port), "--robot", ROBOT]).start()
    camera = start_stage("camera", config, verbose=False)
    preprocess = start_stage("preprocess", config, verbose=False)
    try:
        recorder.wait_line("recording")
        first = client.wait_for("preprocess/edges", timeout=60)
        client.wait_for("preprocess/edges", lambda m: m.header.seq >= first.header.seq + n_edges, timeout=60)
    finally:
        client.close()
        for proc in (camera, preprocess):
            proc.stop()
        assert recorder.stop() == 0, recorder.output()
    summary = json.loads(recorder.lines[-1])
    assert summary["messages"]["preprocess/edges"] >= n_edges // 2, summary


def test_replayed_frames_through_a_fresh_preprocess_give_the_recorded_edges(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    # The sim camera renders the twin court; JPEG keeps the recording small. fps 10 leaves the
    # (shared, 2-core) machine room for the camera, preprocess, recorder and router at once.
    config = write_config(tmp_path / "live.toml", port, '[camera]\nsource = "sim"\nfps = 10\nencoding = "jpeg"\n')
    out = tmp_path / "live.mcap"
    try:
        _record_live_run(tmp_path, port, config, out, n_edges=12)
        recorded = list(read_series([out]))
        frames = {codec.decode(r.data, Frame).header.seq: r.data for r in recorded if r.path == "camera/frame"}
        edges = {e.header.seq: e for e in (codec.decode(r.data, Edges) for r in recorded
                                         if r.path == "preprocess/edges")}
        expected = {seq: edges[seq] for seq in edges if seq in frames}
        assert len(expected) >= 6, f"recorded {len(frames)} frames, {len(edges)} edges"
        assert any(e.n_hits > 20 for e in expected.values()), "the twin's lines produce hits"

        fresh = start_stage("preprocess", config, verbose=False)
        client = BusClient(port)
        client.subscribe("preprocess/edges")
        replayed_frames: queue.Queue[bytes] = queue.Queue()
        client._subs.append(client.session.declare_subscriber(
            TOPICS["camera/frame"].key(ROBOT), lambda sample: replayed_frames.put(bytes(sample.payload))))
        replay = Proc([*PYTHON, "replay", str(out), "--only", "camera/frame", "--connect", endpoint(port),
                       "--wait-subscribers", "30"])
        try:
            client.wait_alive("preprocess")
            replay.start()
            got: dict[int, Edges] = {}
            deadline = time.monotonic() + 60
            while set(expected) - set(got) and time.monotonic() < deadline:
                try:
                    message = next(client.messages("preprocess/edges", timeout=1.5))
                except AssertionError:  # quiet for 1.5 s after the replay ended: nothing more will come
                    if not replay.alive():
                        break
                    continue
                got[message.header.seq] = message
            assert replay.process is not None and replay.process.wait(60) == 0, replay.output()
        finally:
            client.close()
            fresh.stop()
            replay.stop()
        stats = json.loads(replay.lines[-1])
        assert stats["published"] == {"camera/frame": len(frames)}
        bus_frames = []
        while not replayed_frames.empty():
            bus_frames.append(replayed_frames.get_nowait())
        assert bus_frames == [r.data for r in recorded if r.path == "camera/frame"], "replay is bit-exact, in order"

        compared = sorted(set(expected) & set(got))
        differences = [seq for seq in compared if _edges_key(got[seq]) != _edges_key(expected[seq])]
        print(f"process replay: {len(frames)} frames replayed, {len(compared)} of {len(expected)} recorded edges "
              f"compared, {len(differences)} different")
        assert len(compared) >= 0.8 * len(expected), f"only {len(compared)} of {len(expected)} frames came back"
        assert differences == [], (
            f"{len(differences)} of {len(compared)} replayed frames gave other edges than recorded: seqs "
            f"{differences[:10]}; hits recorded/replayed "
            f"{[(expected[s].n_hits, got[s].n_hits) for s in differences[:10]]}")
    finally:
        router.stop()


def test_rewrite_changes_robot_and_restamps_only_when_asked() -> None:
    header = Header(robot_id=ROBOT, seq=9, capture_mono_ns=1_000, capture_wall_ns=2_000, valid=True)
    pose = Pose(header=header, x=1.0, y=2.0, yaw=None, model_name="m", model_version=1, infer_ms=0.5)
    record = Recorded("infer/pose", ROBOT, "msgpack", 0, 0, codec.encode(pose))
    moved = codec.decode(rewrite(record, "robot2", restamp=False), Pose)
    assert moved.header.robot_id == "robot2" and moved.header.capture_wall_ns == 2_000
    assert moved.model_dump(exclude={"header"}) == pose.model_dump(exclude={"header"})
    fresh = codec.decode(rewrite(record, None, restamp=True), Pose)
    assert fresh.header.robot_id == ROBOT and fresh.header.age_ns() < 5e9, "restamped to now"


def test_replay_loops_onto_another_robot(tmp_path: Path) -> None:
    """--loop starts again at the end; --robot readdresses every message it can decode."""
    out = tmp_path / "poses.mcap"
    series = McapSeries(out, Limits(), {})
    for seq in range(4):  # 4 poses, 0.4 s apart: 1.2 s of recording, 0.3 s at --speed 4
        pose = Pose(header=Header(robot_id=ROBOT, seq=seq, capture_mono_ns=seq, capture_wall_ns=seq, valid=True),
                    x=float(seq), y=0.0, model_name="m", model_version=1, infer_ms=0.1)
        series.write(RecordItem("infer/pose", ROBOT, 10**9 + seq * 400_000_000, 0, seq, codec.encode(pose),
                                json_view(pose)))
    series.write(RecordItem("infer/pose", ROBOT, 3 * 10**9, 0, 0, b"\xc1", None))  # undecodable: not readdressed
    series.close()
    port = free_port()
    router = start_router(port)
    client = BusClient(port, "robot2")
    client.subscribe("infer/pose")
    replay = Proc([*PYTHON, "replay", str(out), "--loop", "--speed", "4", "--robot", "robot2",
                   "--connect", endpoint(port), "--wait-subscribers", "30"]).start()
    try:
        seen = [m.header.seq for m, _ in zip(client.messages("infer/pose", timeout=30), range(10))]
    finally:
        client.close()
        assert replay.stop() == 0, replay.output()
        router.stop()
    assert seen[:8] == [0, 1, 2, 3, 0, 1, 2, 3], "the recording again from the start, in order"
    stats = json.loads(replay.lines[-1])
    assert stats["loops"] >= 2 and stats["undecodable_skipped"] >= 2 and stats["rewritten"] >= 8

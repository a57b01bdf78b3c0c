"""`courtloc foxglove`: a real router, the server as its own process, and an independent client of the
Foxglove WebSocket protocol (written here on `websockets`: serverInfo / advertise / subscribe / binary
message data) that subscribes to every channel and
decodes what it receives, each message validated against the schema the server advertised."""
from __future__ import annotations

import asyncio
import base64
import json
import re
import struct
import time
from typing import Any

import numpy as np
import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router

from courtloc.common import codec
from courtloc.common.messages import Edges, Frame, Header, Health, Pose, ShotSolution

pytest.importorskip("foxglove", reason="the foxglove extra (foxglove-sdk)")
websockets = pytest.importorskip("websockets", reason="the test extra")
jsonschema = pytest.importorskip("jsonschema", reason="the test extra")

ROBOT = "robot1"
MESSAGE_DATA = 0x01
# the recording's topic names (one Foxglove layout for both)
POSE, TF, SCENE = "courtloc/robot1/infer/pose/in_frame", "courtloc/robot1/tf", "courtloc/robot1/scene"
IMAGE, HITS = "courtloc/robot1/camera/frame", "courtloc/robot1/preprocess/edges/annotations"
SHOT, HEALTH = "courtloc/robot1/shooter_bridge/solution", "courtloc/robot1/infer/health"


def _header(seq: int, stage: str, valid: bool = True) -> Header:
    header = Header.now(ROBOT, seq, stage)
    header.valid = valid
    return header


def _jpeg() -> bytes:
    import cv2

    ok, data = cv2.imencode(".jpg", np.full((6, 8, 3), 200, np.uint8))
    assert ok
    return data.tobytes()


class FoxgloveClient:
    """The client side of the Foxglove WebSocket protocol: advertise -> subscribe -> binary message data."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[int, dict[str, Any]] = {}
        self.by_subscription: dict[int, dict[str, Any]] = {}
        self.server_info: dict[str, Any] = {}

    async def handshake(self, expected_topics: set[str], timeout: float = 20.0) -> None:
        deadline = time.monotonic() + timeout
        while not expected_topics <= {c["topic"] for c in self.channels.values()}:
            message = json.loads(await asyncio.wait_for(self.ws.recv(), deadline - time.monotonic()))
            if message["op"] == "serverInfo":
                self.server_info = message
            elif message["op"] == "advertise":
                self.channels.update({c["id"]: c for c in message["channels"]})
        subscriptions = [{"id": i + 1, "channelId": cid} for i, cid in enumerate(sorted(self.channels))]
        self.by_subscription = {s["id"]: self.channels[s["channelId"]] for s in subscriptions}
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    async def next_message(self, deadline: float) -> tuple[dict[str, Any], int, dict[str, Any]]:
        while True:
            frame = await asyncio.wait_for(self.ws.recv(), deadline - time.monotonic())
            if isinstance(frame, str):
                continue  # status, advertise of new channels...
            assert frame[0] == MESSAGE_DATA, f"opcode {frame[0]}"
            subscription, log_time = struct.unpack_from("<IQ", frame, 1)
            channel = self.by_subscription[subscription]
            assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
            body = json.loads(frame[13:])
            validator = jsonschema.Draft202012Validator(json.loads(channel["schema"]))
            errors = [e.message for e in validator.iter_errors(body)]
            assert not errors, (channel["topic"], errors)
            return channel, log_time, body


async def _session(url: str, bus: BusClient) -> dict[str, list[dict[str, Any]]]:
    topics = {POSE, TF, SCENE, IMAGE, HITS,
              SHOT, HEALTH}
    seen: dict[str, list[dict[str, Any]]] = {}
    # foxglove.websocket.v1 is the published protocol; the SDK's server names its revision foxglove.sdk.v1
    async with websockets.connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                  max_size=None) as ws:
        assert ws.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
        client = FoxgloveClient(ws)
        await client.handshake(topics)
        deadline = time.monotonic() + 30
        # the scene is re-sent every second: once it arrives, our subscriptions are live
        while SCENE not in seen:
            channel, _, body = await client.next_message(deadline)
            seen.setdefault(channel["topic"], []).append(body)
        hits = np.array([[300, 100, 0, 5], [310, 120, 1, 6]], "<i2")
        bus.put_raw("infer/pose", codec.encode(Pose(header=_header(1, "infer"), x=1.25, y=-0.5, yaw=0.4,
                                                    model_name="m", model_version=1, infer_ms=1.0)))
        bus.put_raw("camera/frame", codec.encode(Frame(header=_header(1, "camera"), width=8, height=6,
                                                       encoding="jpeg", data=_jpeg())))
        bus.put_raw("preprocess/edges", codec.encode(Edges(header=_header(1, "preprocess"), width=640, height=480,
                                                           crop_top=0, n_hits=2, hits=hits.tobytes())))
        bus.put_raw("shooter_bridge/solution", codec.encode(ShotSolution(
            header=_header(1, "shooter_bridge", valid=False), distance_m=float("nan"), rpm=0.0, command="HOLD",
            reason="stale")))
        bus.put_raw("infer/health", codec.encode(Health(
            robot_id=ROBOT, service="infer", uptime_s=3.0, rate_in_hz=30.0, rate_out_hz=30.0, frames_in=90,
            frames_out=90, dropped=0, rejected=0, stale=0, latency_ms_p50=0.8, latency_ms_p99=1.9)))
        wanted = topics - {SCENE}
        while not wanted <= {t for t, bodies in seen.items() if t != TF or any(
                b["child_frame_id"] == "base_link" for b in bodies)}:
            channel, _, body = await client.next_message(deadline)
            seen.setdefault(channel["topic"], []).append(body)
    return seen


@pytest.mark.integration
def test_live_server_speaks_the_foxglove_protocol() -> None:
    port = free_port()
    router = start_router(port)
    server = Proc([*PYTHON, "foxglove", "--port", "0", "--connect", endpoint(port), "--robot", ROBOT]).start()
    bus = BusClient(port, ROBOT)
    try:
        line = server.wait_line("foxglove server on")
        url = re.search(r"ws://\S+", line).group(0)  # type: ignore[union-attr]
        for path in ("infer/pose", "camera/frame", "preprocess/edges", "shooter_bridge/solution", "infer/health"):
            bus.wait_subscribed(path)
        seen = asyncio.run(_session(url, bus))
    finally:
        bus.close()
        server.stop()
        router.stop()
    pose = seen[POSE][0]
    assert (pose["frame_id"], pose["pose"]["position"]["x"], pose["pose"]["position"]["y"]) == ("court", 1.25, -0.5)
    frames = {(t["parent_frame_id"], t["child_frame_id"]) for t in seen[TF]}
    assert {("court", "base_link"), ("base_link", "camera")} <= frames
    entities = {e["id"]: e for e in seen[SCENE][0]["entities"]}
    assert entities["court"]["lines"] and entities["robot"]["cubes"]
    image = seen[IMAGE][0]
    assert image["format"] == "jpeg" and base64.b64decode(image["data"]) == _jpeg()
    points = seen[HITS][0]["points"][0]["points"]
    assert [(p["x"], p["y"]) for p in points] == [(100.5, 300.5), (120.5, 310.5)]
    shot = seen[SHOT][0]
    assert shot["command"] == "HOLD" and shot["distance_m"] is None and shot["reason"] == "stale"
    assert seen[HEALTH][0]["frames_in"] == 90


def test_a_taken_port_is_one_line_and_exit_1(capsys: pytest.CaptureFixture[str]) -> None:
    import foxglove

    from courtloc.cli import main

    taken = foxglove.start_server(port=0)
    try:
        with pytest.raises(SystemExit) as exit_info:
            main(["foxglove", "--port", str(taken.port), "--connect", endpoint(free_port())])
    finally:
        taken.stop()
    err = capsys.readouterr().err.strip()
    assert exit_info.value.code == 1 and len(err.splitlines()) == 1 and "port" in err

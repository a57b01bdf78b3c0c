"""`courtloc monitor` against a real router and a real monitor process; the thumbnail and court on their own."""
from __future__ import annotations

import http.client
import json
import re
import threading
import time
from pathlib import Path
from typing import Any, Callable
from urllib.parse import urlsplit

import cv2
import numpy as np
import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router

from courtloc.common import codec
from courtloc.common.messages import Edges, Frame, GroundTruth, Header, Health, Pose, ShotSolution
from courtloc.monitor.state import court_payload
from courtloc.monitor.thumbnail import Thumbnailer
from courtloc.monitor.watcher import MonitorWatcher
from courtloc.services.deployment import DeploymentConfig
from courtloc.world.court import load_court

ROBOT = "robot1"


# ---- helpers shared with test_monitor_browser.py ------------------------------------------------

def start_monitor(port: int, *extra: str) -> tuple[Proc, str]:
    monitor = Proc([*PYTHON, "monitor", "--port", "0", "--connect", endpoint(port), "--robot", ROBOT, *extra]).start()
    line = monitor.wait_line("monitor for")
    url = re.search(r"http://\S+", line)
    assert url, line
    return monitor, url.group(0)


def wait_state(url: str, predicate: Callable[[dict[str, Any]], bool], timeout: float = 20.0) -> dict[str, Any]:
    """Reads the page's own event stream until a state satisfies `predicate` (deadline `timeout`)."""
    parts = urlsplit(url)
    deadline = time.monotonic() + timeout
    conn = http.client.HTTPConnection(parts.hostname, parts.port, timeout=timeout)
    last: dict[str, Any] = {}
    try:
        conn.request("GET", "/events")
        response = conn.getresponse()
        assert response.status == 200 and response.getheader("Content-Type") == "text/event-stream"
        while time.monotonic() < deadline:
            line = response.readline()
            if not line:
                break
            if line.startswith(b"data: "):
                last = json.loads(line[6:])
                assert "error" not in last, last["error"]  # the monitor could not build its state
                if predicate(last):
                    return last
    finally:
        conn.close()
    raise AssertionError(f"no state matched within {timeout} s; last: {json.dumps(last)[:600]}")


def header(seq: int, stage: str, valid: bool = True) -> Header:
    head = Header.now(ROBOT, seq, stage)
    head.valid = valid
    return head


def synthetic_frame(seq: int, width: int = 160, height: int = 120) -> tuple[Frame, Edges]:
    """A grey frame with a white line, and edge hits along that line's far side."""
    image = np.full((height, width, 3), 60, np.uint8)
    image[70:74, :] = 255
    hits = np.array([[69, c, i, 40] for i, c in enumerate(range(10, width, 20))], dtype="<i2")
    frame = Frame(header=header(seq, "camera"), width=width, height=height, encoding="bgr8", data=image.tobytes())
    edges = Edges(header=header(seq, "preprocess"), width=width, height=height, crop_top=0, n_hits=len(hits),
                  hits=hits.tobytes())
    return frame, edges


class RobotPublisher:
    """Publishes a robot's topics from the test at ~20 Hz on its own thread, until stopped."""

    def __init__(self, client: BusClient, x: float, y: float, yaw: float) -> None:
        self.client = client
        self.pose = (x, y, yaw)
        self.stop = threading.Event()
        self.seq = 0
        self.preview = False  # also publish preprocess/preview (JPEG with the hits drawn)
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "RobotPublisher":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self._thread.join(5)

    def _run(self) -> None:
        put = self.client.put_raw
        while not self.stop.wait(0.05):  # pacing a publisher, not synchronising the test
            self.seq += 1
            x, y, yaw = self.pose
            frame, edges = synthetic_frame(self.seq)
            try:
                put("camera/frame", codec.encode(frame))
                put("preprocess/edges", codec.encode(edges))
                if self.preview and self.seq % 5 == 0:
                    ok, jpeg = cv2.imencode(".jpg", np.full((120, 160, 3), (255, 0, 0), np.uint8))
                    put("preprocess/preview", codec.encode(Frame(header=header(self.seq, "preprocess"), width=160,
                                                                 height=120, encoding="jpeg", data=jpeg.tobytes())))
                put("camera/ground_truth", codec.encode(GroundTruth(header=header(self.seq, "camera"), x=x + 0.1,
                                                                    y=y, yaw=yaw, source="test")))
                put("infer/pose", codec.encode(Pose(header=header(self.seq, "infer"), x=x, y=y, yaw=yaw,
                                                    quality=0.9, model_name="mlp-test", model_version=7,
                                                    infer_ms=1.5)))
                put("shooter_bridge/solution", codec.encode(ShotSolution(
                    header=header(self.seq, "shooter_bridge"), distance_m=3.21, rpm=4321.0, command="SET_RPM")))
                if self.seq % 10 == 0:
                    put("infer/health", codec.encode(Health(
                        robot_id=ROBOT, service="infer", uptime_s=1.0, rate_in_hz=20.0, rate_out_hz=19.5,
                        frames_in=self.seq, frames_out=self.seq, dropped=0, rejected=3, stale=0,
                        latency_ms_p50=1.25, latency_ms_p99=2.5)))
            except Exception:  # the router may be down in a reconnect test: keep trying
                continue


# ---- tests --------------------------------------------------------------------------------------

def test_court_payload_has_the_white_lines() -> None:
    court = load_court("seed-gazebo")
    payload = court_payload(court)
    white = [e for e in payload["elements"] if e["white"]]
    assert len(white) == len(court.white_polygons())
    arc = next(e for e in white if e["name"] == "three-point arc")
    assert 8 <= len(arc["exteriors"][0]) < 1981, "arcs are simplified, not dropped"
    assert json.loads(json.dumps(payload)) == payload


def test_thumbnail_pairs_frame_and_edges_by_seq() -> None:
    watcher = MonitorWatcher(DeploymentConfig(robot_id=ROBOT))
    thumbs = Thumbnailer(watcher, width=160)
    older_frame, older_edges = synthetic_frame(4)
    newer_frame, _ = synthetic_frame(5)
    watcher.rings["camera/frame"].put(codec.encode(older_frame))
    watcher.rings["camera/frame"].put(codec.encode(newer_frame))
    watcher.rings["preprocess/edges"].put(codec.encode(older_edges))
    watcher.rings["preprocess/edges"].put(b"\x93garbage")  # skipped, counted nowhere fatal
    thumb = thumbs.update()
    assert thumb is not None and thumb.source == "frame+edges" and thumb.seq == 4 and thumb.n_hits == 8
    image = cv2.imdecode(np.frombuffer(thumb.jpeg, np.uint8), cv2.IMREAD_COLOR)
    b, g, r = (image[66:73, 8:13, i].astype(int) for i in range(3))  # around the first hit (69, 10)
    assert (r - g).max() > 100, "the hit is drawn in red on the frame"
    assert thumbs.update() is None, "nothing new arrived: no work"


@pytest.mark.integration
def test_monitor_goes_stale_when_the_robot_disconnects_and_recovers(tmp_path: Path) -> None:
    port = free_port()
    router = start_router(port)
    monitor, url = start_monitor(port)
    client = BusClient(port)
    try:
        with RobotPublisher(client, 1.0, -2.0, 0.25) as publisher:
            live = wait_state(url, lambda s: s["status"] == "live" and s["pose"] is not None)
            assert live["pose"]["x"] == pytest.approx(1.0) and live["pose"]["model_version"] == 7
            assert live["solution"]["rpm"] == pytest.approx(4321.0)
            router.kill()
            gone = wait_state(url, lambda s: s["status"] != "live")
            assert gone["status"] == "disconnected" and not gone["connected"], gone["status"]
            assert gone["pose"]["x"] == pytest.approx(1.0), "the last pose stays on the page"
            publisher.pose = (2.5, 1.5, -0.5)
            router = start_router(port)
            back = wait_state(url, lambda s: s["status"] == "live" and s["pose"]["x"] == pytest.approx(2.5),
                              timeout=30)
            assert back["connected"] and back["pose"]["y"] == pytest.approx(1.5)
            assert back["thumb"]["source"] == "frame+edges" and back["frames_subscribed"]
            publisher.preview = True  # a preview appears: the monitor stops pulling raw frames
            shown = wait_state(url, lambda s: s["thumb"]["source"] == "preview" and not s["frames_subscribed"])
            assert shown["thumb"]["n_hits"] == 0
        assert monitor.alive(), "the monitor kept running through the outage"
    finally:
        client.close()
        assert monitor.stop() == 0, monitor.output()
        router.stop()


@pytest.mark.integration
def test_monitor_rejects_a_bad_robot_id() -> None:
    monitor = Proc([*PYTHON, "monitor", "--port", "0", "--robot", "bad/id"]).start()
    assert monitor.process is not None and monitor.process.wait(30) == 2
    assert "robot_id" in monitor.output()

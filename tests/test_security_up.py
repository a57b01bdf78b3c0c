"""`courtloc up` on a locked-down robot: the launcher's router enforces mTLS, passwords and the ACL,
each stage presents its own identity, the status watcher reads as `monitor`, the pit reads as `pit`."""
from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from buskit import PYTHON, Proc, folder_camera_toml, free_port, write_line_frames

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.security import SecurityConfig
from courtloc.common.services_table import TOPICS
from courtloc.security.bundle import init_bundles

pytestmark = pytest.mark.integration


def test_secure_up_runs_the_chain_and_the_pit_reads_it(tmp_path: Path) -> None:
    bundles = init_bundles(tmp_path / "secrets", "robot1", ["robot1.local"], "team A")
    folder = write_line_frames(tmp_path / "frames")
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    config = tmp_path / "robot.toml"
    config.write_text(f"""robot_id = "robot1"
[zenoh]
connect = ["{endpoint}"]
open_retry_s = 0.1
open_retry_max_s = 0.3
[zenoh.security]
dir = "secrets/robot"
[router]
listen = ["{endpoint}"]
secure_dir = "secrets/robot"
[launcher]
services = ["camera", "preprocess"]
{folder_camera_toml(folder)}""")
    summary = tmp_path / "summary.json"
    up = Proc([*PYTHON, "up", "--config", str(config), "--summary-json", str(summary)]).start()
    give_up = threading.Event()
    timer = threading.Timer(60, give_up.set)
    timer.start()
    pit = open_session(ZenohConfig(connect=[endpoint], open_retry_s=0.1, open_retry_max_s=0.3,
                                   security=SecurityConfig(dir=bundles.pit.root, identity="pit")), give_up)
    timer.cancel()
    assert pit is not None, "the pit could not join the launcher's router"
    got = threading.Event()
    edges: list = []

    def on_edges(sample) -> None:  # noqa: ANN001 - zenoh callback
        edges.append(codec.decode(bytes(sample.payload), TOPICS["preprocess/edges"].message))
        if len(edges) >= 10:  # a steady stream, so the launcher's own watcher has seen some too
            got.set()

    sub = pit.declare_subscriber(TOPICS["preprocess/edges"].key("robot1"), on_edges)
    try:
        assert got.wait(60), up.output()
        assert edges[0].header.valid and [s.stage for s in edges[0].header.stamps] == ["camera", "preprocess"]
    finally:
        sub.undeclare()
        pit.close()
        assert up.stop(timeout=30) == 0, up.output()
    report = json.loads(summary.read_text())
    assert report["messages"].get("preprocess/edges", 0) > 0, "the launcher's watcher (monitor) reads the bus"
    assert report["restarts"] == 0, report["restarts_by_process"]

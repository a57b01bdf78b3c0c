"""A stage killed under `courtloc up`: the launcher restarts it within 2 s and the others keep running.

The restart delay is read from the kernel (the new process's start time minus the moment of the
kill), so nothing polls or sleeps to measure it.
"""
from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path

import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, folder_camera_toml, free_port, write_line_frames

from courtloc.bench_procstats import child_processes
from courtloc.common.bus import ZenohConfig, open_session

pytestmark = pytest.mark.integration

RESTART_DEADLINE_S = 2.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def started_at_s(pid: int) -> float:
    """A process's start, in seconds since boot (the kernel's clock ticks)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[19]) / CLOCK_TICKS


def wait_for_router(port: int, timeout: float = 60.0) -> None:
    """Block until a router answers on `port` (the launcher starts its own; its output goes to a log)."""
    give_up = threading.Event()
    timer = threading.Timer(timeout, give_up.set)
    timer.start()
    try:
        session = open_session(ZenohConfig(connect=[endpoint(port)], open_retry_s=0.1, open_retry_max_s=0.3),
                               give_up)
    finally:
        timer.cancel()
    assert session is not None, f"no router on port {port} after {timeout} s"
    session.close()


def up_config(tmp_path: Path, port: int, launcher_extra: str = "") -> Path:
    """A `courtloc up` deployment of camera (a folder of line frames) and preprocess on `port`."""
    folder = write_line_frames(tmp_path / "frames")
    config = tmp_path / "up.toml"
    config.write_text(f"""robot_id = "robot1"
[zenoh]
connect = ["{endpoint(port)}"]
open_retry_s = 0.1
open_retry_max_s = 0.3
[router]
listen = ["{endpoint(port)}"]
[launcher]
services = ["camera", "preprocess"]
restart_backoff_s = 0.5
{launcher_extra}
{folder_camera_toml(folder)}""")
    return config


def test_launcher_restarts_a_killed_stage_and_leaves_the_others(tmp_path: Path) -> None:
    port = free_port()
    summary_path = tmp_path / "summary.json"
    up = Proc([*PYTHON, "up", "--config", str(up_config(tmp_path, port)), "--summary-json",
               str(summary_path)]).start()
    client = None
    try:
        wait_for_router(port)
        client = BusClient(port, reconnect_max_s=0.3)
        client.subscribe("camera/frame")
        client.subscribe("preprocess/edges")
        client.wait_alive("preprocess", timeout=60)
        client.wait_for("preprocess/edges", timeout=60)
        before = child_processes(up.pid)
        assert set(before) == {"router", "camera", "preprocess"}
        last_frame = client.wait_for("camera/frame")

        os.kill(before["preprocess"], signal.SIGKILL)
        killed_at = time.clock_gettime(time.CLOCK_BOOTTIME)
        client.wait_alive("preprocess", alive=False)
        client.wait_alive("preprocess", alive=True, timeout=60)
        after = child_processes(up.pid)
        assert after["preprocess"] != before["preprocess"]
        assert started_at_s(after["preprocess"]) - killed_at <= RESTART_DEADLINE_S
        assert {k: after[k] for k in ("router", "camera")} == {k: before[k] for k in ("router", "camera")}

        client.drain("preprocess/edges")
        edges = client.wait_for("preprocess/edges", lambda m: m.header.seq > last_frame.header.seq, timeout=60)
        assert edges.header.valid, "the restarted stage processes frames again"
        frame = client.wait_for("camera/frame")
        assert frame.header.seq > last_frame.header.seq, "the camera kept counting: it was not restarted"
    finally:
        if client is not None:
            client.close()
        code = up.stop(timeout=30)
    assert code == 0, up.output()
    summary = json.loads(summary_path.read_text())
    assert summary["restarts_by_process"] == {"router": 0, "camera": 0, "preprocess": 1}

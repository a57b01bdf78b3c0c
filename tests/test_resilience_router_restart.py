"""The router killed and restarted: every stage resumes within 2 s of the new router being ready,
and no stage restarts (same processes throughout).

Stages and the test's client reconnect with a short back-off (`open_retry_max_s`, which also drives
zenoh's own reconnection); the 2 s is a deadline on awaited messages, not a sleep.
"""
from __future__ import annotations

import time
from pathlib import Path

import pytest
from buskit import BusClient, folder_camera_toml, free_port, start_router, start_stage, write_config, write_line_frames

from courtloc.common.services_table import SERVICES

pytestmark = pytest.mark.integration

RESUME_DEADLINE_S = 2.0


def _chain_config(tmp_path: Path, port: int) -> Path:
    folder = write_line_frames(tmp_path / "frames")
    return write_config(tmp_path / "chain.toml", port, folder_camera_toml(folder), health_period_s=0.2)


def _sent_after(message: object, ready_ns: int) -> bool:
    """Data: the newest stamp is the stage's own (monotonic clocks agree across processes on one host).
    Health has no stamp, but nothing crossed while no router ran, so any health sample is new."""
    header = getattr(message, "header", None)
    return header is None or header.stamps[-1].mono_ns > ready_ns


def test_all_stages_resume_after_router_restart(tmp_path: Path) -> None:
    stages = list(SERVICES)
    data = {"camera": "camera/frame", "preprocess": "preprocess/edges"}  # streams that flow without a model
    port = free_port()
    router = start_router(port)
    config = _chain_config(tmp_path, port)
    if "shooter_bridge" in stages:
        config.write_text(config.read_text() + f'[shooter_bridge.link]\nport = "{tmp_path / "no-mcu"}"\n')
    procs = {name: start_stage(name, config, verbose=False) for name in stages}
    client = BusClient(port, reconnect_max_s=0.3)
    watched = [*(data[s] for s in stages if s in data), *(f"{s}/health" for s in stages)]
    for path in watched:
        client.subscribe(path)
    try:
        for path in watched:
            client.wait_for(path, timeout=60)
        pids = {name: proc.pid for name, proc in procs.items()}
        router.kill()
        router = start_router(port)
        ready_ns = time.monotonic_ns()  # the new router has printed that it listens
        deadline = time.monotonic() + RESUME_DEADLINE_S
        for path in watched:
            client.drain(path)  # anything queued now crossed the old router
        for path in watched:
            fresh = client.wait_for(path, lambda m: _sent_after(m, ready_ns),
                                    timeout=max(0.01, deadline - time.monotonic()))
            assert not hasattr(fresh, "header") or fresh.header.stamps[-1].stage == path.split("/")[0]
        assert {name: proc.pid for name, proc in procs.items()} == pids
        assert all(proc.alive() for proc in procs.values()), "no stage restarted or died"
    finally:
        client.close()
        for proc in procs.values():
            proc.stop()
        router.stop()

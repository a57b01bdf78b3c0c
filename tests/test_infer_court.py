"""The infer stage on a real router, about where the robot is rather than which model: the deployment's court
picks the bundled package and refuses another court's model; without evidence between the court's mirror
twins the pose stays invalid ('ambiguous') until the pit sets it (`courtloc pose set`, a separate process);
a stage killed mid-run resumes on the right side from the pose it saved, not from the configured start."""
from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import pytest
from buskit import PYTHON, BusClient, Proc, free_port, start_router, start_stage, write_config
from infer_models import TwinFrames, first_valid_pose, request_pose, run_model_cli

from courtloc.services.deployment import load_deployment
from courtloc.services.infer.service import bundled_default
from courtloc.stage_cli import stage_argv

pytestmark = pytest.mark.integration

MINUS_X = (-2.0, 1.5, 0.4)  # in the -x half: its mirror twin (2, -1.5, 0.4 + pi) sees the same lines


def _near(pose, truth, tol: float = 0.1) -> bool:  # noqa: ANN001
    return math.hypot(pose.x - truth[0], pose.y - truth[1]) < tol


def _pose_set(config: Path, *args: str) -> tuple[int, dict]:
    done = subprocess.run([*PYTHON, "pose", "set", *args, "--config", str(config), "--json", "-"],
                          capture_output=True, text=True, timeout=60)
    return done.returncode, (json.loads(done.stdout) if done.stdout else {"stderr": done.stderr})


@pytest.fixture(scope="module")
def bus():  # noqa: ANN201
    port = free_port()
    router = start_router(port)
    client = BusClient(port)
    client.subscribe("infer/pose")
    try:
        yield port, client
    finally:
        client.close()
        router.stop()


def test_robocon_deployment_serves_its_package_and_refuses_the_seed_one(bus, tmp_path: Path) -> None:  # noqa: ANN001
    port, client = bus
    config = write_config(tmp_path / "robot.toml", port, f"""
[camera]
source = "device"
[infer]
store = "{tmp_path / 'store'}"
start = {{ x = 3.0, y = -2.0, yaw_deg = 90.0 }}
""")
    config.write_text('court = "robocon2025"\n' + config.read_text())  # a top-level key, before any table
    infer = start_stage("infer", config)
    try:
        line = infer.wait_line("serving model", timeout=60)
        assert "court robocon2025, camera robocon2025" in line, line
        infer.wait_line("infer running for robot", timeout=60)
        frames = TwinFrames([(3.0, -2.0, math.pi / 2)], court="robocon2025", camera="robocon2025")
        pose, _ = first_valid_pose(client, frames, 1)
        assert pose.header.valid and _near(pose, frames.poses[0]), pose
        code, reply, _ = run_model_cli(config, "push", str(bundled_default()))
        assert code == 1 and not reply["ok"], reply
        assert "model is for court 'seed-gazebo', this deployment's court is 'robocon2025'" in reply["reason"]
    finally:
        infer.stop()


def test_ambiguous_until_the_pit_sets_the_pose(bus, tmp_path: Path) -> None:  # noqa: ANN001
    port, client = bus
    # No start and no simulated camera to take one from: nothing tells the mirror twins apart.
    config = write_config(tmp_path / "robot.toml", port, f"""
[camera]
source = "device"
[infer]
store = "{tmp_path / 'store'}"
""")
    infer = start_stage("infer", config)
    try:
        infer.wait_line("infer running for robot", timeout=60)
        frames = TwinFrames([MINUS_X])
        poses = [request_pose(client, frames, seq) for seq in range(1, 7)]
        assert not any(p.header.valid for p in poses)
        assert poses[-1].reason == "ambiguous", [p.reason for p in poses]
        code, reply = _pose_set(config, "9", "0", "0")  # off the court: refused, nothing changes
        assert code == 1 and not reply["ok"] and "not on court" in reply["reason"], reply
        code, reply = _pose_set(config, "-4", "-3", "100")  # on the court, but no view there: not confirmed
        assert code == 0 and reply["ok"], reply
        poses = [request_pose(client, frames, seq) for seq in range(7, 11)]
        assert not any(p.header.valid for p in poses), [(p.x, p.y, p.reason) for p in poses]
        code, reply = _pose_set(config, "-2.2", "1.4", "20", "--std", "0.5")
        assert code == 0 and reply["ok"], reply
        pose, _ = first_valid_pose(client, frames, 11)  # confirmed over a few frames
        assert pose.header.valid and _near(pose, MINUS_X), pose
    finally:
        infer.stop()


def test_killed_mid_run_it_resumes_on_the_right_side(bus, tmp_path: Path) -> None:  # noqa: ANN001
    port, client = bus
    store = tmp_path / "store"
    body = f"""
[camera]
source = "device"
[infer]
store = "{store}"
drift_mps = 0.2
"""
    # The run started in the -x half; the restarted stage is told (wrongly, for mid-run) to start in +x.
    started = write_config(tmp_path / "start.toml", port, body + 'start = { half = "-x" }\n')
    restarted = write_config(tmp_path / "restart.toml", port, body + 'start = { half = "+x" }\n')
    frames = TwinFrames([MINUS_X])
    infer = start_stage("infer", started)
    try:
        infer.wait_line("infer running for robot", timeout=60)
        pose, seq = first_valid_pose(client, frames, 1)
        assert pose.header.valid and _near(pose, MINUS_X), pose
        for seq in range(seq, seq + 20):  # a second of tracking: the stage saves its pose twice a second
            assert request_pose(client, frames, seq).header.valid
    finally:
        infer.kill()  # kill -9: no shutdown code runs
    assert (store.parent / "store.last-pose.json").is_file()
    infer = start_stage("infer", restarted)
    try:
        infer.wait_line("resuming from the pose saved", timeout=60)
        infer.wait_line("infer running for robot", timeout=60)
        poses = [request_pose(client, frames, s) for s in range(seq + 1, seq + 6)]
        assert all(_near(p, MINUS_X) for p in poses if p.header.valid), [(p.x, p.y, p.reason) for p in poses]
        assert poses[-1].header.valid, [(p.x, p.y, p.reason) for p in poses]
    finally:
        infer.stop()
    # A new run (`courtloc up` starts each stage with --fresh-run, restarts without): the pose the last run
    # saved seconds ago is not its evidence; the configured start is.
    assert (store.parent / "store.last-pose.json").is_file()
    infer = Proc(stage_argv("infer", restarted, load_deployment(restarted), verbose=1, fresh_run=True)).start()
    try:
        infer.wait_line("infer running for robot", timeout=60)
        assert not [line for line in infer.lines if "resuming from the pose saved" in line]
    finally:
        infer.stop()

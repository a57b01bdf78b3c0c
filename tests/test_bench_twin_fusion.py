"""The twin's MCU through the real chain: its odometry reaches infer over a pty and the bridge, and the
fused pose stays valid through a vision blackout in which a vision-only tracker on the same frames goes
invalid.

One chain (router + camera with the sim source and its twin MCU + preprocess + infer + shooter_bridge, as
`courtloc bench twin --fusion on` runs it). The vision-only tracker is the infer stage's own shadow
runner (`courtloc model shadow`) on the same model, started before the camera: it acquires from the
configured start like the active tracker and tracks the same frames without odometry (fusion serves the
active tracker only), so both answers are for the same frames.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
from pathlib import Path

import pytest
from buskit import BusClient, free_port

from courtloc.bench_twin import STAGES_BEFORE_CAMERA, deployment_for
from courtloc.lab.metrics import WRONG_M
from courtloc.launcher import Supervisor, write_effective_config
from courtloc.model_client import ModelClient
from courtloc.sim.render import RenderOptions
from courtloc.sim.scenarios import scenario

pytestmark = [pytest.mark.integration, pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs ptys")]

SECONDS = 6.0  # the blackout scenario at 6 s: lines in view until 2.4 s (the chain warms up), none over [2.4, 4.2)
FPS = 30.0


def _until_seq(client: BusClient, path: str, seq: int, timeout: float = 60.0) -> list:
    """Every message of `path` up to and including the first one of frame `seq` or later."""
    out = []
    for message in client.messages(path, timeout):
        out.append(message)
        if message.header.seq >= seq:
            return out
    raise AssertionError("unreachable")


def test_fused_pose_stays_valid_through_a_blackout_where_vision_only_goes_invalid(tmp_path: Path) -> None:
    # Clean frames: this is about the odometry's path and the blackout, not about vision under randomised
    # light (whose occasional 0.2 m glitch the fused tracker takes for a kidnap: README, bench twin --fusion).
    blackout = scenario("blackout", "seed-gazebo", SECONDS)
    sc = dataclasses.replace(blackout, sim=blackout.sim.model_copy(update={"render": RenderOptions()}))
    start_s, end_s = sc.blackout_s
    # With the MCU the twin runs in real time: frame k shows sim time >= k / fps (more when frames were
    # missed), so frames up to this one include every blind one; which are blind, their stamps say.
    last_blind = int(math.ceil(end_s * FPS))
    args = argparse.Namespace(camera=None, config=None, fps=FPS, tell_start="pose")
    port = free_port()
    config = deployment_for(sc, args, port, tmp_path / "store", {}, mcu_link=tmp_path / "mcu")
    supervisor = Supervisor(config, write_effective_config(config, tmp_path), tmp_path / "logs")
    (tmp_path / "logs").mkdir()
    children = {c.name: c for c in supervisor.children}
    client = None
    try:
        children["router"].start(tmp_path / "logs")
        assert children["router"].ready.wait(15.0), "router not ready"
        client = BusClient(port, wait_for_router_s=15.0)
        for path in ("camera/ground_truth", "infer/pose", "infer/shadow_pose", "shooter_bridge/odometry",
                     "infer/health"):
            client.subscribe(path)
        for name in STAGES_BEFORE_CAMERA:
            children[name].start(tmp_path / "logs")
        for name in STAGES_BEFORE_CAMERA:
            client.wait_alive(name, timeout=60.0)
        models = ModelClient(client.session, config.robot_id)
        active_model = next(m for m in models.list().models if m.active)
        reply = models.shadow(active_model.version, active_model.name)
        assert reply.ok, reply.reason
        children["camera"].start(tmp_path / "logs")

        # The bridge opened the camera's pty and publishes the twin MCU's odometry.
        odometry = client.wait_for("shooter_bridge/odometry", lambda m: m.wheels_valid and m.gyro_valid)
        assert odometry.source == "mcu" and odometry.header.valid
        truths = {t.header.capture_mono_ns: t for t in _until_seq(client, "camera/ground_truth", last_blind)}
        zero = min(truths)  # frame 0: sim time 0
        last = max(truths)
        assert (last - zero) / 1e9 >= end_s
        poses = _until_seq(client, "infer/pose", truths[last].header.seq)
        shadows = _until_seq(client, "infer/shadow_pose", truths[last].header.seq)
        # The infer stage says how it kept the pose valid: on odometry.
        fused_reasons = sorted({p.reason for p in poses if not p.header.valid})
        try:
            client.wait_for("infer/health", lambda h: h.detail.get("fusion.valid_on_odometry", 0) > 0)
        except AssertionError:
            raise AssertionError(f"no pose valid on odometry; invalid fused poses' reasons {fused_reasons}") from None
    finally:
        if client is not None:
            client.close()
        supervisor.stop_all()

    def blind(pose) -> bool:  # noqa: ANN001
        return start_s * 1e9 <= pose.header.capture_mono_ns - zero < end_s * 1e9

    def before(pose) -> bool:  # noqa: ANN001
        return pose.header.capture_mono_ns - zero < start_s * 1e9

    shadow_before = [p for p in shadows if before(p) and p.header.valid]
    assert shadow_before, "the vision-only tracker was never valid before the blackout: nothing to compare"
    assert any(p.header.valid and before(p) for p in poses)
    shadow_blind = [p for p in shadows if blind(p)]
    fused_blind = [p for p in poses if blind(p)]
    assert len(shadow_blind) >= 10 and len(fused_blind) >= 10  # frames dropped under load are fine, a few are not
    assert not any(p.header.valid for p in shadow_blind), [p.reason for p in shadow_blind]
    assert all(p.header.valid for p in fused_blind), [p.reason for p in fused_blind if not p.header.valid]
    # Valid, and right: no fused blind pose is "valid and wrong" (the project's threshold).
    errors = [math.hypot(p.x - truths[p.header.capture_mono_ns].x, p.y - truths[p.header.capture_mono_ns].y)
              for p in fused_blind if p.header.capture_mono_ns in truths]
    assert errors and max(errors) < WRONG_M, errors

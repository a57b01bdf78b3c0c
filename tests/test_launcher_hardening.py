"""The launcher's restart policy and its refusal to join a pipeline it did not start.

The back-off tests drive the supervisor's decisions with an explicit clock over real child processes
(killed with SIGKILL), so they check the policy without waiting for it.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from buskit import PYTHON, BusClient, Proc, endpoint, free_port, start_router

from courtloc.common.services_table import all_liveliness_key
from courtloc.launcher import Child, Supervisor
from courtloc.port_holder import endpoint_port, port_holder
from courtloc.services.deployment import DeploymentConfig, LauncherConfig, load_deployment

SLEEPER = [sys.executable, "-c", "import time; time.sleep(120)"]


def _supervisor(tmp_path: Path, **launcher: object) -> Supervisor:
    config = DeploymentConfig(launcher=LauncherConfig(services=[], run_router=False, **launcher))
    supervisor = Supervisor(config, tmp_path / "deployment.json", tmp_path)
    return supervisor


def _kill(child: Child) -> None:
    assert child.process is not None
    child.process.kill()
    child.process.wait()


def test_stage_backoff_doubles_then_resets_after_a_healthy_run(tmp_path: Path) -> None:
    supervisor = _supervisor(tmp_path, restart_backoff_s=0.5, restart_backoff_max_s=8.0, restart_healthy_s=10.0)
    child = Child("stage", SLEEPER, 0.5, 8.0)
    supervisor.children.append(child)
    child.start(tmp_path, now=0.0)
    try:
        t = 0.0
        delays = []
        for _ in range(4):  # four quick deaths: 0.5, 1, 2, 4 s
            t += 0.1
            _kill(child)
            supervisor.check(now=t)
            delays.append(child.next_start - t)
            t = child.next_start
            supervisor.check(now=t)
            assert child.alive()
        assert delays == pytest.approx([0.5, 1.0, 2.0, 4.0])
        # It now runs healthily for longer than restart_healthy_s: the next death gets the first delay.
        t += 10.5
        supervisor.check(now=t)
        _kill(child)
        supervisor.check(now=t + 0.1)
        assert child.next_start - (t + 0.1) == pytest.approx(0.5)
        assert child.restarts == 4
    finally:
        child.stop(timeout=5)


def test_a_killed_router_is_restarted_at_once_and_never_waits_long(tmp_path: Path) -> None:
    config = DeploymentConfig(launcher=LauncherConfig(services=[], run_router=True, restart_backoff_s=0.5))
    supervisor = Supervisor(config, tmp_path / "deployment.json", tmp_path)
    router = supervisor.children[0]
    assert router.name == "router"
    router.argv = SLEEPER  # the restart policy, not zenoh, is under test here
    router.ready_line = None
    router.start(tmp_path, now=0.0)
    try:
        t = 0.0
        waits = []
        for _ in range(5):
            t += 0.05
            old_pid = router.process.pid
            _kill(router)
            supervisor.check(now=t)  # the first check after the death
            waits.append(max(router.next_start - t, 0.0) if router.next_start else 0.0)
            if not router.alive():
                t = router.next_start
                supervisor.check(now=t)
            assert router.alive() and router.process.pid != old_pid
        # 0.1 s doubling, capped by the stages' first delay (a stage's own cap is restart_backoff_max_s)
        assert waits == pytest.approx([0.1, 0.2, 0.4, 0.5, 0.5])
    finally:
        router.stop(timeout=5)


def test_port_holder_names_the_listening_process() -> None:
    port = free_port()
    holder = subprocess.Popen([sys.executable, "-c", f"""
import socket, sys, time
s = socket.socket(); s.bind(("127.0.0.1", {port})); s.listen(); print("ok", flush=True); time.sleep(60)
"""], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "ok"
        named = port_holder(port)
        assert named is not None and f"pid {holder.pid} " in named
    finally:
        holder.kill()
        holder.wait()
    assert endpoint_port("tls/0.0.0.0:7447") == 7447 and endpoint_port("tcp/[::1]:80") == 80


@pytest.mark.integration
def test_up_refuses_when_its_router_port_is_taken_and_joins_nothing(tmp_path: Path) -> None:
    port = free_port()
    other = start_router(port)  # another pipeline's router on our port
    seen: list[str] = []
    client = BusClient(port)
    watcher = client.session.liveliness().declare_subscriber(
        all_liveliness_key("robot1"), lambda sample: seen.append(str(sample.key_expr)), history=True)
    config = tmp_path / "up.toml"
    config.write_text(f"""robot_id = "robot1"
[zenoh]
connect = ["{endpoint(port)}"]
[router]
listen = ["{endpoint(port)}"]
[launcher]
services = ["preprocess"]
""")
    up = Proc([*PYTHON, "up", "--config", str(config), "--duration", "20"]).start()
    try:
        assert up.process is not None
        code = up.process.wait(timeout=60)
        line = up.wait_line("courtloc up:")
    finally:
        up.kill()
        watcher.undeclare()
        client.close()
        other.stop()
    assert code != 0, up.output()
    assert f"port {port}" in line and f"pid {other.pid}" in line
    assert "Traceback" not in up.output()
    assert seen == []  # no stage of ours ever joined the other pipeline


@pytest.mark.integration
def test_router_killed_under_up_comes_back_each_time_with_the_short_delay(tmp_path: Path) -> None:
    """Three router kills in a row under a real `courtloc up`: each is relaunched after 0.1, 0.2, 0.4 s
    (the launcher's decision, logged), not the stages' growing back-off, and the chain flows again."""
    import os
    import signal

    from test_resilience_stage_kill import up_config, wait_for_router

    from courtloc.bench_procstats import child_processes

    port = free_port()
    config = up_config(tmp_path, port, "restart_healthy_s = 600  # no reset between the kills, however slow")
    up = Proc([*PYTHON, "up", "--config", str(config)]).start()
    client = None
    try:
        wait_for_router(port)
        client = BusClient(port, reconnect_max_s=0.3)
        client.subscribe("preprocess/edges")
        client.wait_for("preprocess/edges", timeout=60)
        for kill, delay in enumerate(("0.1", "0.2", "0.4"), start=1):
            os.kill(child_processes(up.pid)["router"], signal.SIGKILL)
            line = up.wait_line(f"router exited (code -9); restarting in {delay} s", timeout=30)
            assert line and len([ln for ln in up.lines if "router exited" in ln]) == kill
            client.drain("preprocess/edges")
            client.wait_for("preprocess/edges", timeout=60)  # the chain flows through the new router
    finally:
        if client is not None:
            client.close()
        up.stop()


def test_the_first_start_is_a_fresh_run_and_a_restart_resumes(tmp_path: Path) -> None:
    """`courtloc up` starts each stage with --fresh-run (a pose saved by an earlier run is not resumed) and
    restarts it without (mid-run, the pose its predecessor saved is the evidence)."""
    config_path = tmp_path / "up.toml"
    config_path.write_text('robot_id = "robot1"\n')
    supervisor = Supervisor(load_deployment(config_path), config_path, tmp_path)
    infer = next(child for child in supervisor.children if child.name == "infer")
    assert infer.first_argv is not None and "--fresh-run" in infer.first_argv
    assert "--fresh-run" not in infer.argv
    assert [a for a in infer.first_argv if a != "--fresh-run"] == infer.argv

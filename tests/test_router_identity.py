"""`courtloc up` never lets its stages join a pipeline it did not start, also after its router died.

The router `courtloc up` starts gets a zenoh id of that run; each stage is told it (`--expect-router`) and
leaves any other router it finds itself connected to: with one log line and a non-zero exit, so the launcher
restarts it until its own router is back. Real router and stage processes; every wait is on an event.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import zenoh
from buskit import BusClient, Proc, endpoint, free_port, write_config

from courtloc.common.bus import check_zenoh_id, new_router_id
from courtloc.common.runtime import FOREIGN_ROUTER_EXIT
from courtloc.common.services_table import all_liveliness_key
from courtloc.launcher import Supervisor
from courtloc.router_process import RouterSettings, router_argv
from courtloc.services.deployment import DeploymentConfig, LauncherConfig, load_deployment
from courtloc.stage_cli import stage_argv


def _router(port: int, zenoh_id: str) -> Proc:
    router = Proc(router_argv(RouterSettings(robot_id="robot1", listen=[endpoint(port)], zenoh_id=zenoh_id))).start()
    router.wait_line("router listening")
    return router


def _stage(config: Path, expect_router: str) -> Proc:
    """preprocess as `courtloc up` starts it: its own entry point, told which router it must be on."""
    return Proc(stage_argv("preprocess", config, load_deployment(config), verbose=1,
                           expect_router=expect_router)).start()


def _wait_until_it_leaves(stage: Proc, theirs: str, ours: str) -> int:
    """The stage's exit code, once it has exited and said which router it found instead of ours."""
    assert stage.process is not None
    code = stage.process.wait(timeout=60)
    stage.wait_line(f"connected to router {theirs}, not {ours}")
    return code


@pytest.mark.integration
def test_a_stage_expecting_another_router_exits_with_one_line_and_never_joins(tmp_path: Path) -> None:
    port = free_port()
    ours, theirs = new_router_id(), new_router_id()
    router = _router(port, theirs)  # another pipeline's router, already on the endpoint
    client = BusClient(port)
    seen: list[str] = []
    watcher = client.session.liveliness().declare_subscriber(
        all_liveliness_key("robot1"), lambda sample: seen.append(str(sample.key_expr)), history=True)
    stage = _stage(write_config(tmp_path / "deploy.toml", port), ours)
    try:
        code = _wait_until_it_leaves(stage, theirs, ours)
    finally:
        stage.kill()
        watcher.undeclare()
        client.close()
        router.stop()
    assert code == FOREIGN_ROUTER_EXIT, stage.output()
    assert len([line for line in stage.lines if "connected to router" in line]) == 1, stage.output()
    assert "Traceback" not in stage.output()
    assert seen == []  # the check runs before anything is declared: the stage never came alive there


@pytest.mark.integration
def test_a_stage_on_its_own_router_runs_and_leaves_the_one_that_took_the_port(tmp_path: Path) -> None:
    """Told the right id, the stage runs. Then the scenario of the issue: our router dies and another
    pipeline's router takes the port before ours is back; the stage reconnects to it and leaves at once."""
    port = free_port()
    ours, theirs = new_router_id(), new_router_id()
    router = _router(port, ours)
    client = BusClient(port)
    client.subscribe("preprocess/health")
    stage = _stage(write_config(tmp_path / "deploy.toml", port, health_period_s=0.2), ours)
    foreign = None
    try:
        client.wait_alive("preprocess")
        client.wait_for("preprocess/health")  # serving: reports flow
        assert stage.alive()
        client.close()
        router.kill()  # SIGKILL: no goodbye, as a crash
        foreign = _router(port, theirs)
        code = _wait_until_it_leaves(stage, theirs, ours)
    finally:
        stage.kill()
        router.kill()
        if foreign is not None:
            foreign.stop()
    assert code == FOREIGN_ROUTER_EXIT, stage.output()
    assert "Traceback" not in stage.output()


def test_up_gives_its_router_an_id_of_the_run_and_tells_each_stage(tmp_path: Path) -> None:
    def supervisor(**fields: object) -> Supervisor:
        return Supervisor(DeploymentConfig(**fields), tmp_path / "deployment.json", tmp_path)

    first, second = supervisor(), supervisor()
    assert first.router_id is not None and second.router_id is not None and first.router_id != second.router_id
    check_zenoh_id(first.router_id)
    router = next(c for c in first.children if c.name == "router")
    assert RouterSettings.model_validate_json(router.argv[-1]).zenoh_id == first.router_id
    for child in first.children[1:]:
        for argv in (child.argv, child.first_argv):
            assert argv is not None and argv[argv.index("--expect-router") + 1] == first.router_id
    # No router of its own: it joins an existing one on purpose; peers may link to several routers.
    for fields in ({"launcher": LauncherConfig(run_router=False)}, {"zenoh": {"mode": "peer"}}):
        assert all("--expect-router" not in child.argv for child in supervisor(**fields).children)


def test_zenoh_ids_are_ones_zenoh_accepts() -> None:
    """zenoh refuses an id with a leading zero: every generated one is a valid session id."""
    ids = {new_router_id() for _ in range(200)}
    assert len(ids) == 200 and all(check_zenoh_id(i) == i and len(i) == 32 for i in ids)
    config = zenoh.Config()
    for zid in list(ids)[:5]:
        config.insert_json5("id", f'"{zid}"')
    with pytest.raises(ValueError):
        check_zenoh_id("0a" + "1" * 30)

"""Secure by default: listening beyond loopback needs the security bundle or an explicit, nagging `insecure = true`."""
from __future__ import annotations

import logging
import threading
from pathlib import Path

import pytest
from buskit import PYTHON, Proc, free_port

from courtloc.common.config_loader import ConfigError
from courtloc.common.exposure import exposed_endpoints, insecure_exposure, is_loopback, warn_while_insecure
from courtloc.services.deployment import load_deployment

PROFILES = Path(__file__).resolve().parents[1] / "deploy" / "configs"


def test_shipped_robot_profile_requires_the_bundle() -> None:
    robot = load_deployment(PROFILES / "robot.toml")
    assert exposed_endpoints([*robot.router.listen, *robot.zenoh.listen]), "the robot's router is reachable from the pit"
    assert robot.router.secure_dir is not None and robot.zenoh.security is not None and not robot.insecure
    assert all(ep.startswith("tls/") for ep in (*robot.router.listen, *robot.zenoh.connect))


@pytest.mark.parametrize("name", sorted(p.name for p in PROFILES.glob("*.toml")))
def test_no_shipped_profile_listens_beyond_loopback_unsecured(name: str) -> None:
    config = load_deployment(PROFILES / name)
    assert not config.insecure
    assert not exposed_endpoints([*config.router.listen, *config.zenoh.listen]) or config.router.secure_dir is not None


@pytest.mark.parametrize("listen", ["tcp/0.0.0.0:7447", "tcp/192.168.1.10:7447", "tcp/[::]:7447",
                                   "tcp/robot1.local:7447"])
def test_listening_beyond_loopback_without_the_bundle_is_refused(tmp_path: Path, listen: str) -> None:
    path = tmp_path / "open.toml"
    path.write_text(f'[router]\nlisten = ["{listen}"]\n')
    with pytest.raises(ConfigError, match="router.listen.*secure_dir"):
        load_deployment(path)
    path.write_text(f'insecure = true\n[router]\nlisten = ["{listen}"]\n')
    assert load_deployment(path).insecure


def test_peer_listening_beyond_loopback_needs_security_too(tmp_path: Path) -> None:
    path = tmp_path / "peer.toml"
    path.write_text('[zenoh]\nmode = "peer"\nlisten = ["tcp/0.0.0.0:7448"]\n')
    with pytest.raises(ConfigError, match="zenoh.listen"):
        load_deployment(path)


@pytest.mark.parametrize("endpoint, loopback", [
    ("tcp/127.0.0.1:7447", True), ("tls/localhost:7447", True), ("tcp/[::1]:7447", True),
    ("tcp/127.0.0.1:7447#iface=lo", True), ("tcp/0.0.0.0:7447", False), ("tls/robot1.local:7447", False),
])
def test_loopback_endpoints(endpoint: str, loopback: bool) -> None:
    assert is_loopback(endpoint) is loopback


def test_insecure_warning_repeats_until_stopped() -> None:
    logger = logging.getLogger("test.insecure")
    seen: list[str] = []
    twice = threading.Event()

    class Collect(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            seen.append(record.getMessage())
            if len(seen) >= 2:
                twice.set()

    handler = Collect()
    logger.addHandler(handler)
    stop = threading.Event()
    try:
        thread = warn_while_insecure(["tcp/0.0.0.0:7447"], stop, logger, period_s=0.01)
        assert thread is not None and twice.wait(10)
        stop.set()
        thread.join(5)
        assert not thread.is_alive()
    finally:
        logger.removeHandler(handler)
    assert all("INSECURE" in line and "tcp/0.0.0.0:7447" in line for line in seen)
    assert warn_while_insecure([], stop, logger) is None
    assert insecure_exposure(["tcp/0.0.0.0:1"], secured=True) == []


@pytest.mark.integration
def test_router_refuses_an_open_listen_and_nags_when_told_insecure(tmp_path: Path) -> None:
    port = free_port()
    refused = Proc([*PYTHON, "router", "--listen", f"tcp/0.0.0.0:{port}"]).start()
    assert refused.process is not None and refused.process.wait(30) == 2
    assert "insecure = true" in refused.output() and "Traceback" not in refused.output()

    config = tmp_path / "open.toml"
    config.write_text(f'insecure = true\n[router]\nlisten = ["tcp/0.0.0.0:{port}"]\n')
    router = Proc([*PYTHON, "router", "--config", str(config)]).start()
    try:
        line = router.wait_line("INSECURE")
        assert f"tcp/0.0.0.0:{port}" in line
    finally:
        router.stop()


def test_monitor_refuses_to_serve_beyond_loopback_unless_insecure(tmp_path: Path) -> None:
    config = tmp_path / "pit.toml"
    config.write_text('robot_id = "robot1"\n')
    refused = Proc([*PYTHON, "monitor", "--host", "0.0.0.0", "--port", "0", "--config", str(config)]).start()
    assert refused.process is not None and refused.process.wait(60) == 2
    assert "insecure = true" in refused.output() and "Traceback" not in refused.output()

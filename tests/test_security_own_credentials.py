"""Each stage gets only its own key: systemd copies one identity out of the root-only bundle into the
unit's private `$CREDENTIALS_DIRECTORY`, and a process given one reads nothing else."""
from __future__ import annotations

import os
import queue
import shutil
from pathlib import Path

import pytest
from buskit import PYTHON, Proc, folder_camera_toml, free_port, write_line_frames

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.security import CLIENT_CREDENTIALS, ROUTER_CREDENTIALS, SYSTEMD_CREDENTIALS_ENV, SecurityConfig
from courtloc.common.services_table import TOPICS
from courtloc.security.bundle import init_bundles

UNITS = Path(__file__).resolve().parents[1] / "deploy" / "systemd"
SECRETS = "/etc/courtloc/secrets"


def _credentials(unit: str) -> dict[str, str]:
    # LoadCredential= repeats: configparser would keep the last, so read the lines themselves
    lines = [line.split("=", 1)[1] for line in (UNITS / unit).read_text().splitlines()
             if line.startswith("LoadCredential=")]
    return dict(line.split(":", 1) for line in lines)


def test_stage_unit_loads_exactly_its_own_identity() -> None:
    loaded = _credentials("courtloc-stage@.service")
    assert tuple(loaded) == CLIENT_CREDENTIALS
    for name, source in loaded.items():
        assert source == f"{SECRETS}/ca.pem" if name == "ca.pem" else source == f"{SECRETS}/identities/%i/{name}"


def test_router_unit_loads_only_the_router_credentials() -> None:
    loaded = _credentials("courtloc-router.service")
    assert tuple(loaded) == ROUTER_CREDENTIALS
    assert all("identities" not in source for source in loaded.values())


def _flat_copy(files: dict[str, Path], folder: Path) -> Path:
    """What systemd's LoadCredential= makes: the named files, flat, in a folder of their own."""
    folder.mkdir(mode=0o700)
    for name, source in files.items():
        shutil.copyfile(source, folder / name)
    return folder


@pytest.mark.integration
def test_router_and_stage_run_on_their_own_credentials_only(tmp_path: Path) -> None:
    bundles = init_bundles(tmp_path / "secrets", "robot1", ["robot1.local"], "team A")
    robot = bundles.robot
    router_creds = _flat_copy(dict(zip(ROUTER_CREDENTIALS, (robot.ca_certificate, robot.router_certificate,
                                                            robot.router_private_key, robot.users_dictionary))),
                              tmp_path / "router-creds")
    camera_creds = _flat_copy(dict(zip(CLIENT_CREDENTIALS, (robot.ca_certificate, robot.certificate("camera"),
                                                            robot.private_key("camera"), robot.user_file("camera"),
                                                            robot.password_file("camera")))),
                              tmp_path / "camera-creds")
    assert sorted(os.listdir(camera_creds)) == sorted(CLIENT_CREDENTIALS)  # no other stage's key in reach
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    nowhere = tmp_path / "no-bundle-here"  # the config names a bundle that does not exist
    config = tmp_path / "robot.toml"
    config.write_text(f"""robot_id = "robot1"
[zenoh]
connect = ["{endpoint}"]
open_retry_s = 0.1
open_retry_max_s = 0.3
[zenoh.security]
dir = "{nowhere}"
[router]
listen = ["{endpoint}"]
secure_dir = "{nowhere}"
{folder_camera_toml(write_line_frames(tmp_path / "frames"))}""")
    env = {k: v for k, v in os.environ.items() if k != SYSTEMD_CREDENTIALS_ENV}
    router = Proc([*PYTHON, "router", "--config", str(config)], env={**env, SYSTEMD_CREDENTIALS_ENV: str(router_creds)})
    camera = Proc([*PYTHON, "run", "camera", "--config", str(config)],
                  env={**env, SYSTEMD_CREDENTIALS_ENV: str(camera_creds)})
    router.start()
    pit = None
    try:
        router.wait_line("router listening")
        camera.start()
        pit = open_session(ZenohConfig(connect=[endpoint], security=SecurityConfig(dir=bundles.pit.root,
                                                                                   identity="pit")))
        received: queue.Queue[bytes] = queue.Queue()
        frames = pit.declare_subscriber(TOPICS["camera/frame"].key("robot1"),
                                        lambda sample: received.put(bytes(sample.payload)))
        try:
            payload = received.get(timeout=60)
        except queue.Empty:
            raise AssertionError(f"no frame from the camera:\n{camera.output()}\n{router.output()}") from None
        frame = codec.decode(payload, TOPICS["camera/frame"].message)
        assert frame.header.stamps[0].stage == "camera"
        frames.undeclare()
    finally:
        if pit is not None:
            pit.close()
        camera.stop()
        router.stop()
    # without the credentials folder the same config names the missing bundle file and stops
    missing = Proc([*PYTHON, "run", "camera", "--config", str(config)], env=env).start()
    assert missing.process is not None and missing.process.wait(30) == 2
    assert str(nowhere) in missing.output()

"""The robot's router with mTLS, passwords and the table-derived ACL, against real processes and sessions.

Negative checks use a barrier instead of a sleep: the forbidden message is sent first and an allowed
one right after on the same session and priority; zenoh keeps that order on a link, so once the
allowed one has arrived the forbidden one would have arrived before it.
"""
from __future__ import annotations

import queue
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np
import pytest
import zenoh
from buskit import PYTHON, Proc, free_port, start_stage

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, build_zenoh_config, open_session
from courtloc.common.security import SecurityConfig
from courtloc.common.services_table import CONTROLS, TOPICS, liveliness_key, robot_wildcard_key
from courtloc.security.bundle import Bundles, init_bundles

pytestmark = pytest.mark.integration

ROBOT = "robot1"


@dataclass
class SecureBus:
    port: int
    ours: Bundles
    theirs: Bundles  # another team: its own CA
    tmp: Path

    @property
    def endpoint(self) -> str:
        return f"tls/127.0.0.1:{self.port}"

    def config(self, bundle: Path, identity: str, **overrides: object) -> ZenohConfig:
        return ZenohConfig(connect=[self.endpoint], security=SecurityConfig(dir=bundle, identity=identity),
                           **overrides)

    def open(self, bundle: Path, identity: str) -> zenoh.Session:
        return open_session(self.config(bundle, identity))


@pytest.fixture(scope="module")
def bus(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecureBus]:
    tmp = tmp_path_factory.mktemp("secure")
    ours = init_bundles(tmp / "ours", ROBOT, ["robot1.local"], "team A")
    theirs = init_bundles(tmp / "theirs", ROBOT, ["robot1.local"], "team B")
    port = free_port()
    config = tmp / "router.toml"
    config.write_text(f'robot_id = "{ROBOT}"\n[router]\nlisten = ["tls/127.0.0.1:{port}"]\n'
                      f'secure_dir = "{ours.robot.root}"\n')
    router = Proc([*PYTHON, "router", "--config", str(config)]).start()
    router.wait_line("router listening")
    try:
        yield SecureBus(port, ours, theirs, tmp)
    finally:
        router.stop()


class Recorder:
    """Every sample of the subscribed keys, in arrival order."""

    def __init__(self) -> None:
        self.samples: queue.Queue[tuple[str, bytes]] = queue.Queue()

    def __call__(self, sample: zenoh.Sample) -> None:
        self.samples.put((str(sample.key_expr), bytes(sample.payload)))

    def until(self, key: str, timeout: float = 20.0) -> list[str]:
        """Keys received up to and including the first sample on `key`."""
        seen = []
        while True:
            got, _ = self.samples.get(timeout=timeout)
            seen.append(got)
            if got == key:
                return seen


def send_until_seen(send: Callable[[], None], recorder: Recorder, key: str, what: str) -> list[str]:
    """Repeat `send` until `key` arrives (a new subscription takes a moment to reach the router);
    returns every key received up to it, so a forbidden one that got through is in the list."""
    for _ in range(100):
        send()
        try:
            return recorder.until(key, timeout=0.2)
        except queue.Empty:
            continue
    raise AssertionError(what)


def _refused(cfg: ZenohConfig) -> bool:
    try:
        session = zenoh.open(build_zenoh_config(cfg))
    except zenoh.ZError:
        return True
    session.close()
    return False


def test_intruders_cannot_open_a_session(bus: SecureBus) -> None:
    robot = bus.ours.robot.root
    legit = bus.config(robot, "camera")
    assert not _refused(legit), "the legitimate identity must get in (else the refusals prove nothing)"

    no_cert = ZenohConfig(connect=[bus.endpoint])
    assert _refused(no_cert)
    assert _refused(ZenohConfig(connect=[f"tcp/127.0.0.1:{bus.port}"])), "plain TCP is not accepted"

    wrong_password = tmp_copy(robot, bus.tmp / "wrong_pw", "camera")
    (wrong_password / "identities/camera/password").write_text("not-the-password\n")
    assert _refused(bus.config(wrong_password, "camera"))

    other_team = bus.theirs.robot.root  # same robot id and identity names, another CA
    assert _refused(bus.config(other_team, "camera"))

    # Our CA trusted, their client certificate presented with our password: still refused.
    mixed = tmp_copy(robot, bus.tmp / "mixed", "camera")
    for name in ("cert.pem", "key.pem"):
        (mixed / "identities/camera" / name).write_bytes((other_team / "identities/camera" / name).read_bytes())
    assert _refused(bus.config(mixed, "camera"))


def tmp_copy(bundle: Path, target: Path, identity: str) -> Path:
    """A bundle with only the CA and one identity, to alter without touching the original."""
    (target / "identities" / identity).mkdir(parents=True)
    (target / "ca.pem").write_bytes((bundle / "ca.pem").read_bytes())
    for item in (bundle / "identities" / identity).iterdir():
        (target / "identities" / identity / item.name).write_bytes(item.read_bytes())
    return target


def test_stage_publishes_its_topic_and_pit_reads_it(bus: SecureBus) -> None:
    frames = bus.tmp / "frames"
    frames.mkdir(exist_ok=True)
    cv2.imwrite(str(frames / "a.png"), np.full((24, 32, 3), 7, np.uint8))
    config = bus.tmp / "camera.toml"
    config.write_text(f'robot_id = "{ROBOT}"\n[zenoh]\nconnect = ["{bus.endpoint}"]\n'
                      f'[zenoh.security]\ndir = "{bus.ours.robot.root}"\n'
                      f'[camera]\nsource = "folder"\nfps = 20\n[camera.folder]\npath = "{frames}"\npattern = "*.png"\n')
    pit = bus.open(bus.ours.pit.root, "pit")
    alive = threading.Event()
    received = Recorder()
    subs = [pit.declare_subscriber(TOPICS["camera/frame"].key(ROBOT), received),
            pit.liveliness().declare_subscriber(liveliness_key(ROBOT, "camera"), lambda s: alive.set(), history=True)]
    camera = start_stage("camera", config)
    try:
        key, payload = received.samples.get(timeout=30)
        frame = codec.decode(payload, TOPICS["camera/frame"].message)
        assert key == TOPICS["camera/frame"].key(ROBOT) and frame.header.valid and frame.width == 32
        assert alive.wait(10), "the pit sees the stage's liveliness token"
    finally:
        for sub in subs:
            sub.undeclare()
        pit.close()
        assert camera.stop() == 0, camera.output()


def test_a_stage_may_publish_only_its_own_topics(bus: SecureBus) -> None:
    pit = bus.open(bus.ours.pit.root, "pit")
    everything = Recorder()
    sub = pit.declare_subscriber(robot_wildcard_key(ROBOT), everything)
    forger = bus.open(bus.ours.robot.root, "preprocess")
    try:
        own = TOPICS["preprocess/edges"].key(ROBOT)
        forbidden = [TOPICS[p].key(ROBOT) for p in ("infer/pose", "camera/frame", "shooter_bridge/solution",
                                                     "infer/health")]
        def forge_then_send_own() -> None:
            for key in forbidden:
                forger.put(key, b"forged")
            forger.put(own, b"allowed")

        seen = send_until_seen(forge_then_send_own, everything, own, "the stage's own topic never reached the pit")
        assert seen == [own], f"forbidden keys got through: {seen}"
    finally:
        sub.undeclare()
        forger.close()
        pit.close()


def test_a_stage_may_subscribe_only_its_inputs(bus: SecureBus) -> None:
    reader = bus.open(bus.ours.robot.root, "preprocess")  # input: camera/frame only
    got = Recorder()
    frame_key, truth_key = TOPICS["camera/frame"].key(ROBOT), TOPICS["camera/ground_truth"].key(ROBOT)
    subs = [reader.declare_subscriber(truth_key, got), reader.declare_subscriber(frame_key, got)]
    camera = bus.open(bus.ours.robot.root, "camera")
    try:
        def send_truth_then_frame() -> None:
            camera.put(truth_key, b"truth")  # allowed for the camera, not readable by preprocess
            camera.put(frame_key, b"frame")

        seen = send_until_seen(send_truth_then_frame, got, frame_key, "the stage never received its input")
        assert truth_key not in seen
    finally:
        for sub in subs:
            sub.undeclare()
        camera.close()
        reader.close()


@pytest.mark.parametrize("control", sorted(CONTROLS))
def test_only_the_pit_may_call_model_control(bus: SecureBus, control: str) -> None:
    spec = CONTROLS[control]
    owner = bus.open(bus.ours.robot.root, spec.service)
    asked: list[str] = []

    def answer(query: zenoh.Query) -> None:
        asked.append(str(query.key_expr))
        query.reply(query.key_expr, b"ok")

    queryable = owner.declare_queryable(spec.key(ROBOT), answer)
    pit = bus.open(bus.ours.pit.root, "pit")
    camera = bus.open(bus.ours.robot.root, "camera")
    monitor = bus.open(bus.ours.robot.root, "monitor")
    try:
        for _ in range(50):  # until the queryable's declaration has reached the router
            if [r.ok for r in pit.get(spec.key(ROBOT), timeout=2.0) if r.ok]:
                break
        else:
            raise AssertionError("the pit never got a reply")
        calls_by_pit = len(asked)
        for intruder in (camera, monitor):
            assert [r for r in intruder.get(spec.key(ROBOT), timeout=1.0)] == []
        assert len(asked) == calls_by_pit, "a non-pit query reached the service"
    finally:
        queryable.undeclare()
        for session in (camera, monitor, pit, owner):
            session.close()

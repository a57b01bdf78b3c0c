"""Hot swap under a 30 fps stream: a real router, the infer stage as its own process, `courtloc model push`
as another; the test plays the preprocess stage, publishing twin frames' Edges at 30 Hz."""
from __future__ import annotations

import json
import subprocess
import threading
from typing import Iterator

import numpy as np
import pytest
import zenoh
from buskit import PYTHON, BusClient, free_port, start_router, start_stage, write_config
from infer_models import Pacer, TwinFrames, relabelled_package

from courtloc.common import codec
from courtloc.common.services_table import TOPICS

pytestmark = pytest.mark.integration

FPS = 30.0
FRAMES_AFTER_SWAP = 30
POSE_WAIT_S = 5.0  # a pose later than this is a lost frame (a tracked frame takes a few ms)
# A drive across the +x half and back, 2.5 m each way at up to 2.4 m/s (frames at most 8 cm apart, so the
# geometric model tracks every frame). It slows down before turning back as a robot must: the motion
# filter is tuned on real drives, and an instant reversal at full speed (a step of 90 m/s^2) is
# overshot by up to ~14 cm with the bundled settings (docs/localizer.md, Known limits).
_EASED = (1.0 - np.cos(np.pi * np.linspace(0.0, 1.0, 50))) / 2.0
PATH = [(2.0 + 1.5 * t, -1.5 + 2.0 * t, 0.4 - 0.6 * t) for t in _EASED]
TOLERANCE_M = 0.15


@pytest.fixture(scope="module")
def frames() -> TwinFrames:
    return TwinFrames(PATH + PATH[::-1])  # there and back, so the stream loops without a jump


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    tmp = tmp_path_factory.mktemp("hotswap")
    port = free_port()
    router = start_router(port)
    config = write_config(tmp / "robot.toml", port, f'[infer]\nstore = "{tmp / "store"}"\n')
    client = BusClient(port)
    client.subscribe("infer/pose")
    infer = start_stage("infer", config)
    try:
        infer.wait_line("infer running for robot", timeout=60)
        yield {"tmp": tmp, "config": config, "client": client, "infer": infer}
    finally:
        client.close()
        infer.stop()
        router.stop()


def _warm_up(client: BusClient, publisher: zenoh.Publisher, frames: TwinFrames) -> int:
    """Frames one at a time until the stage answers with a valid pose: routes are up and the model has
    its first (slow, global) fix, so the stream that follows is served in tracking mode."""
    for seq in range(20):
        publisher.put(codec.encode(frames.edges(0, seq)))
        try:
            pose = client.wait_for("infer/pose", lambda p, s=seq: p.header.seq == s, timeout=5.0)
        except AssertionError:
            continue  # the first put can precede the subscription's route through the router
        if pose.header.valid:
            return seq + 1
    raise AssertionError("the infer stage never answered with a valid pose")


def _timings(poses: dict, seq: int) -> str:
    """Publish-to-pose lag and inference time of the frames before `seq` (to tell a slow stage from a lost one)."""
    rows = []
    for s in range(seq - 4, seq + 3):
        if s in poses:
            stamps = {st.stage: st.mono_ns for st in poses[s].header.stamps}
            lag = (stamps["infer"] - stamps["preprocess"]) / 1e6
            rows.append(f"{s}: lag {lag:.1f} ms, infer {poses[s].infer_ms:.1f} ms")
        else:
            rows.append(f"{s}: lost")
    return "; ".join(rows)


def test_swap_under_30fps_loses_no_frame(robot: dict, frames: TwinFrames) -> None:
    client: BusClient = robot["client"]
    package = relabelled_package(robot["tmp"] / "swapped", "swapped")
    # BLOCK: the test's own publisher must never be the one dropping a frame.
    publisher = client.session.declare_publisher(TOPICS["preprocess/edges"].key(client.robot_id),
                                                 congestion_control=zenoh.CongestionControl.BLOCK)
    first_seq = _warm_up(client, publisher, frames)
    client.drain("infer/pose")

    published: list[int] = []
    poses: dict = {}
    swap_done = threading.Event()
    stop = threading.Event()
    after_swap: list[int] = []  # seqs published after the push's reply came back

    def stream() -> None:
        # At most 30 fps and one frame in flight: the stage keeps the latest frame per input, so with two
        # in flight a worker that a loaded machine stalls for one frame period replaces one (CI lost seq 41
        # of 405 that way, 330 frames before the swap). In lockstep a missing pose is a frame the swap lost.
        pacer = Pacer(FPS)
        seq = first_seq
        while pacer.wait(stop):
            publisher.put(codec.encode(frames.edges(seq - first_seq, seq)))
            published.append(seq)
            try:
                poses[seq] = client.wait_for("infer/pose", lambda p, s=seq: p.header.seq == s, timeout=POSE_WAIT_S)
            except AssertionError:
                pass  # lost: the assertions below say which
            if swap_done.is_set():
                after_swap.append(seq)
                if len(after_swap) >= FRAMES_AFTER_SWAP:
                    return
            seq += 1

    streamer = threading.Thread(target=stream, daemon=True)
    streamer.start()
    try:
        # The pit laptop is another machine; niced, the CLI here does not take the robot's CPU from the stage.
        push = subprocess.run(["nice", "-n", "10", *PYTHON, "model", "push", str(package),
                               "--config", str(robot["config"]), "--json", "-"], capture_output=True, text=True, timeout=120)
    finally:
        swap_done.set()
    streamer.join(timeout=30)
    stop.set()
    publisher.undeclare()
    assert push.returncode == 0, push.stdout + push.stderr
    reply = json.loads(push.stdout)
    assert reply["ok"] and reply["name"] == "swapped" and reply["version"] == 1, reply

    # No frame is lost. Storing, validating, loading and warming the new model happen on the control
    # thread, validation in a niced child process (the stage only loads the validated model and runs its
    # golden inputs once to warm it up); the swap itself is one reference assignment between two frames,
    # and the new model tracks on from the last pose instead of starting a global search. So every seq
    # gets its pose.
    missing = sorted(set(published) - set(poses))
    first_new = min((s for s, p in poses.items() if p.model_name == "swapped"), default=None)
    assert not missing, (f"{len(missing)} of {len(published)} frames got no pose: {missing[:20]}; first pose of "
                         f"the new model: seq {first_new}; around the first loss: "
                         f"{_timings(poses, missing[0]) if missing else ''}")
    assert len(published) > FRAMES_AFTER_SWAP + 15, "the push finished before the stream was under way"

    versions = [(poses[s].model_name, poses[s].model_version) for s in published]
    assert set(versions) <= {("default", 1), ("swapped", 1)}, set(versions)
    switch = versions.index(("swapped", 1))
    assert switch > 0, "no frame was served by the old model during the push"
    assert all(v == ("swapped", 1) for v in versions[switch:]), "a pose came from the old model after the swap"
    assert all(poses[s].model_name == "swapped" for s in after_swap)
    # Every pose is a whole model's answer for its own frame: valid and where the twin frame was rendered.
    for seq in published:
        pose = poses[seq]
        truth = frames.poses[(seq - first_seq) % len(frames.poses)]
        assert pose.header.valid, (seq, pose.reason)
        assert np.hypot(pose.x - truth[0], pose.y - truth[1]) < TOLERANCE_M, (seq, pose, truth)

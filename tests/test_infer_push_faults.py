"""A push that goes wrong on the robot's side: the service killed mid-push (the same push resumes after a
restart) and a disk that fills up while a model is stored. Real router, real stage processes, the
`courtloc model` CLI as its own process, real files (a real small filesystem for the full disk)."""
from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Any, Iterator

import pytest
from buskit import BusClient, free_port, start_router, start_stage, write_config
from infer_models import TwinFrames, first_valid_pose, relabelled_package, run_model_cli, tiny_paper_model

from courtloc.common.messages import Pose
from courtloc.model_client import ModelClient
from courtloc.services.infer.store import INCOMING, ModelStore

pytestmark = pytest.mark.integration

BIG_PAD = 30 * 2**20  # a large-ish push: the package plus an extra 30 MiB file
TRUTH = (2.0, -1.5, 0.4)


class Bench:
    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.port = free_port()
        self.router = start_router(self.port)
        self.client = BusClient(self.port)
        self.client.subscribe("infer/pose")
        self.frames = TwinFrames([TRUTH])
        self.big = relabelled_package(tmp / "big", "big", pad_bytes=BIG_PAD)
        self.seq = 0

    def config(self, name: str, store: Path) -> Path:
        # drift_mps: the twin robot stands still while pushes pause the frames for seconds (a robot that waits).
        return write_config(self.tmp / f"{name}.toml", self.port, f'[infer]\nstore = "{store}"\ndrift_mps = 0.1\n')

    def start(self, config: Path):  # noqa: ANN201 - buskit.Proc
        infer = start_stage("infer", config)
        infer.wait_line("infer running for robot", timeout=60)
        return infer

    def pose(self) -> Pose:
        """The first valid pose of the next few frames: after a start or a pause of more than a second (a push
        takes longer) the localizer acquires again, over a few frames (docs/localizer.md, "Acquisition")."""
        pose, next_seq = first_valid_pose(self.client, self.frames, self.seq + 1)
        self.seq = next_seq - 1
        return pose

    def model(self, config: Path, *args: str) -> tuple[int, dict[str, Any], str]:
        return run_model_cli(config, *args)


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Bench]:
    bench = Bench(tmp_path_factory.mktemp("faults"))
    try:
        yield bench
    finally:
        bench.client.close()
        bench.router.stop()


class _Killed(Exception):
    pass


def test_kill_mid_push_leaves_a_consistent_store_and_the_push_resumes(bench: Bench) -> None:
    store_dir = bench.tmp / "store"
    config = bench.config("crash", store_dir)
    infer = bench.start(config)
    try:
        total = sum(p.stat().st_size for p in bench.big.iterdir() if p.is_file())  # what a push carries

        def kill_a_third_in(done: int, _total: int) -> None:
            if done >= total // 3:
                infer.kill()  # SIGKILL: no shutdown code runs
                raise _Killed

        with pytest.raises(_Killed):
            ModelClient(bench.client.session, bench.client.robot_id).push(bench.big, chunk_bytes=2**20,
                                                                         progress=kill_a_third_in)
        assert not infer.alive()
        store = ModelStore(store_dir)
        assert [str(m.ref) for m in store.models()] == ["default/1"], "a half-pushed version is visible"
        assert str(store.record().active) == "default/1"
        partial = [p for p in (store_dir / INCOMING).rglob("*") if p.is_file()]
        assert 0 < sum(p.stat().st_size for p in partial) < total

        infer = bench.start(config)
        code, reply, log = bench.model(config, "push", str(bench.big), "--chunk-mb", "1")
        assert code == 0 and (reply["name"], reply["version"]) == ("big", 1), reply
        resumed = re.search(r"resuming push \w+ at (\d+) of (\d+) bytes", log)
        assert resumed, log
        assert total // 3 <= int(resumed.group(1)) < total and int(resumed.group(2)) == total

        code, reply, _ = bench.model(config, "list")
        listed = {(m["name"], m["version"]): m for m in reply["models"]}
        assert set(listed) == {("default", 1), ("big", 1)}
        assert listed[("big", 1)]["active"] and listed[("big", 1)]["size_bytes"] == total
        pose = bench.pose()
        assert (pose.model_name, pose.header.valid) == ("big", True)
        assert math.hypot(pose.x - TRUTH[0], pose.y - TRUTH[1]) < 0.1
        assert not any((store_dir / INCOMING).iterdir())
    finally:
        infer.stop()



def test_disk_full_refuses_the_push_and_keeps_the_store(bench: Bench, small_disk: Path) -> None:
    store_dir = small_disk / "store"
    config = bench.config("small", store_dir)
    infer = bench.start(config)
    try:
        free_before = os.statvfs(small_disk).f_bavail
        code, reply, _ = bench.model(config, "push", str(bench.big))
        assert code == 1 and not reply["ok"] and "disk full" in reply["reason"], reply
        assert [str(m.ref) for m in ModelStore(store_dir).models()] == ["default/1"]
        assert not any((store_dir / INCOMING).iterdir()), "the partial upload was not removed"
        assert os.statvfs(small_disk).f_bavail == free_before, "the failed push still holds disk space"
        pose = bench.pose()
        assert pose.header.valid and pose.model_name == "default"
        # The store is still usable: a model that fits goes in.
        code, reply, _ = bench.model(config, "push", str(tiny_paper_model(bench.tmp / "small" / "model.onnx",
                                                                          "small")))
        assert code == 0 and reply["name"] == "small", reply
        assert bench.pose().model_name == "small"
    finally:
        infer.stop()

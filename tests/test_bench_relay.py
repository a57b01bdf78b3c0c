"""The transport baseline of `bench pipeline --relay` runs end to end: router + 4 hop processes in shared memory."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from buskit import free_port, start_router

from courtloc.bench_pipeline import measure_relay
from courtloc.common.realtime import RealtimeConfig, StageRealtime

pytestmark = pytest.mark.integration


def test_relay_frames_reach_the_last_hop() -> None:
    relay = measure_relay(2.0, warmup_frames=5)
    assert relay["n"] > 0, "no frame crossed the 4 hops"
    assert relay["e2e_latency_ms_p50"] is not None and relay["e2e_latency_ms_p50"] > 0


def test_each_relay_hop_runs_with_its_stages_realtime_settings() -> None:
    """With `[realtime]` on, the chain's stages are pinned: the relay baseline must be too, or the ratio
    between them measures the settings, not the work. Hop 2 stands for infer."""
    cpus = sorted(os.sched_getaffinity(0))
    pinned = cpus[-1]
    realtime = RealtimeConfig(enabled=True, stages={"infer": StageRealtime(cpus=[pinned])})
    port = free_port()
    router = start_router(port)
    hop = subprocess.Popen([sys.executable, "-m", "courtloc.bench_relay", "--hop", "2", "--port", str(port),
                            "--seconds", "1", "--realtime", realtime.model_dump_json()],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert hop.stdout.readline().strip() == "ready", hop.stderr.read()
        assert os.sched_getaffinity(hop.pid) == {pinned}
        for task in os.listdir(f"/proc/{hop.pid}/task"):  # zenoh's threads too: they were started after the setting
            assert os.sched_getaffinity(int(task)) == {pinned}
    finally:
        hop.kill()
        hop.communicate()
        router.kill()

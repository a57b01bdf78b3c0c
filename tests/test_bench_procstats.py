"""The bench's /proc reader: which child is which stage, its CPU time and PSS."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from courtloc.bench_procstats import ProcessSampler, _read, child_processes

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/self/smaps_rollup"), reason="Linux /proc")


def test_children_are_named_by_role_and_measured() -> None:
    # argv as the launcher writes it: `... -m courtloc.services.camera ...`; the child burns CPU, then waits
    code = "import sys; sum(i * i for i in range(3_000_000)); print('ready', flush=True); sys.stdin.read()"
    child = subprocess.Popen([sys.executable, "-c", code, "courtloc.services.camera", "--config", "x.toml"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"
        assert child_processes(os.getpid()).get("camera") == child.pid
        sample = _read(child.pid, 0.0)
        assert sample is not None and sample.cpu_s > 0 and sample.pss_kb > 1000
    finally:
        child.communicate("")
    assert child_processes(os.getpid()).get("camera") is None, "an exited child is not reported"


def test_report_divides_cpu_by_frames_between_first_and_last_sample() -> None:
    from courtloc.bench_procstats import _Sample

    sampler = ProcessSampler()
    sampler.first["infer"] = _Sample(pid=1, at=10.0, cpu_s=2.0, pss_kb=200 * 1024)
    sampler.last["infer"] = _Sample(pid=1, at=20.0, cpu_s=2.6, pss_kb=210 * 1024)
    report = sampler.report(frames_per_s=30.0)["processes"]["infer"]
    assert report == {"cpu_ms_per_frame": 2.0, "cpu_percent": 6.0, "pss_mb": 210.0}

"""Optional real-time settings: applied at stage start when enabled, refused with one line when not permitted."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import ValidationError

from courtloc.common.realtime import RealtimeConfig, RealtimeError, StageRealtime, apply_realtime

pytestmark = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="Linux scheduling calls")


def _child() -> subprocess.Popen:
    """A process to apply settings to, so the test process keeps its own scheduling."""
    return subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)


def test_off_by_default_and_when_disabled() -> None:
    assert apply_realtime("preprocess", RealtimeConfig()) == []
    disabled = RealtimeConfig(enabled=False, stages={"preprocess": StageRealtime(cpus=[0])})
    assert apply_realtime("preprocess", disabled) == []


def test_affinity_is_applied_to_the_stage_process() -> None:
    cpu = min(os.sched_getaffinity(0))
    child = _child()
    try:
        applied = apply_realtime("infer", RealtimeConfig(enabled=True, stages={"infer": StageRealtime(cpus=[cpu])}),
                                 pid=child.pid)
        assert applied == [f"cpus [{cpu}]"]
        assert os.sched_getaffinity(child.pid) == {cpu}
    finally:
        child.communicate(b"")


def test_threads_started_before_the_settings_take_them_too() -> None:
    """numpy's BLAS pool starts its threads at import, before a stage applies its settings: every thread of the
    process is pinned, not only the main one."""
    cpu = max(os.sched_getaffinity(0))
    child = subprocess.Popen([sys.executable, "-c", "import sys, threading; threading.Thread(target=sys.stdin.read, "
                              "daemon=True).start(); print('started', flush=True); sys.stdin.read()"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline() == b"started\n"
        tasks = [int(task) for task in os.listdir(f"/proc/{child.pid}/task")]
        assert len(tasks) >= 2
        pinned = RealtimeConfig(enabled=True, stages={"infer": StageRealtime(cpus=[cpu])})
        apply_realtime("infer", pinned, pid=child.pid)
        assert all(os.sched_getaffinity(task) == {cpu} for task in tasks)
    finally:
        child.communicate(b"")


def test_a_cpu_this_machine_lacks_is_refused_naming_the_field() -> None:
    absent = max(os.sched_getaffinity(0)) + 64
    config = RealtimeConfig(enabled=True, stages={"camera": StageRealtime(cpus=[absent])})
    with pytest.raises(RealtimeError, match=r"realtime\.stages\.camera\.cpus: CPU\(s\) \[\d+\] not available"):
        apply_realtime("camera", config)


def test_sched_fifo_applies_where_permitted_and_is_refused_clearly_elsewhere() -> None:
    config = RealtimeConfig(enabled=True, stages={"shooter_bridge": StageRealtime(fifo_priority=5)})
    child = _child()
    try:
        try:
            applied = apply_realtime("shooter_bridge", config, pid=child.pid)
        except RealtimeError as exc:
            assert "fifo_priority: the OS refused SCHED_FIFO" in str(exc)
            assert os.sched_getscheduler(child.pid) == os.SCHED_OTHER, "nothing half-applied"
        else:
            assert applied == ["SCHED_FIFO 5"] and os.sched_getscheduler(child.pid) == os.SCHED_FIFO
    finally:
        child.communicate(b"")


def test_unknown_stage_and_bad_priority_fail_validation() -> None:
    with pytest.raises(ValidationError, match="unknown stage"):
        RealtimeConfig(stages={"camrea": StageRealtime(cpus=[0])})
    with pytest.raises(ValidationError, match="fifo_priority"):
        StageRealtime(fifo_priority=100)


def test_run_refuses_to_start_a_stage_it_cannot_pin(tmp_path: Path) -> None:
    absent = max(os.sched_getaffinity(0)) + 64
    config = tmp_path / "rt.toml"
    config.write_text(f"[realtime]\nenabled = true\n[realtime.stages.camera]\ncpus = [{absent}]\n")
    result = subprocess.run([sys.executable, "-m", "courtloc", "run", "camera", "--config", str(config)],
                            capture_output=True, text=True, timeout=60, check=False)
    assert result.returncode == 2
    assert "realtime.stages.camera.cpus" in result.stderr and "Traceback" not in result.stderr

"""Optional real-time settings of a stage process: CPU affinity and SCHED_FIFO priority.

Off by default. On the robot they keep a stage on its own core and ahead of best-effort work (the way
openpilot pins its daemons). Applied once at stage start, before the bus is touched; what the OS does
not permit is refused with one line saying why, and the stage does not start half-configured.

    [realtime]
    enabled = true
    [realtime.stages.preprocess]
    cpus = [2]
    fifo_priority = 10
"""
from __future__ import annotations

import os
from typing import Callable

from pydantic import BaseModel, ConfigDict, Field, field_validator

from courtloc.common.services_table import SERVICES


class RealtimeError(RuntimeError):
    """The OS (or this machine) does not permit a requested setting."""


class StageRealtime(BaseModel):
    model_config = ConfigDict(extra="forbid")

    cpus: list[int] | None = Field(default=None, min_length=1, description="CPU ids this stage may run on")
    fifo_priority: int | None = Field(default=None, ge=1, le=99, description="SCHED_FIFO priority (1-99)")


class RealtimeConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    enabled: bool = False
    stages: dict[str, StageRealtime] = Field(default_factory=dict)

    @field_validator("stages")
    @classmethod
    def _known_stages(cls, stages: dict[str, StageRealtime]) -> dict[str, StageRealtime]:
        unknown = sorted(set(stages) - set(SERVICES))
        if unknown:
            raise ValueError(f"unknown stage(s) {unknown}; known: {sorted(SERVICES)}")
        return stages


def _threads(pid: int) -> list[int]:
    """The thread ids of process `pid` (0: this one), its main thread first. Affinity and policy are per thread:
    threads started before the settings (numpy's BLAS pool, at import) keep the old ones unless set too; threads
    started after inherit them."""
    main = pid or os.getpid()
    try:
        others = sorted(int(task) for task in os.listdir(f"/proc/{main}/task") if int(task) != main)
    except OSError:  # no /proc: the main thread alone
        others = []
    return [main, *others]


def _each_thread(pid: int, setting: Callable[[int], None]) -> None:
    """`setting` on every thread of `pid`; the main thread's refusal is the process's, a thread that ended
    meanwhile is no error."""
    main, *others = _threads(pid)
    setting(main)
    for tid in others:
        try:
            setting(tid)
        except ProcessLookupError:
            pass


def apply_realtime(stage: str, config: RealtimeConfig, pid: int = 0) -> list[str]:
    """Apply `stage`'s settings to every thread of process `pid` (0: this one); returns what was applied, for
    the log."""
    settings = config.stages.get(stage)
    if not config.enabled or settings is None:
        return []
    applied: list[str] = []
    if settings.cpus is not None:
        if not hasattr(os, "sched_setaffinity"):
            raise RealtimeError(f"realtime.stages.{stage}.cpus: CPU affinity is not available on this OS")
        present = os.sched_getaffinity(0)
        missing = sorted(set(settings.cpus) - present)
        if missing:
            raise RealtimeError(f"realtime.stages.{stage}.cpus: CPU(s) {missing} not available here "
                                f"(allowed: {sorted(present)})")
        _each_thread(pid, lambda tid: os.sched_setaffinity(tid, settings.cpus))
        applied.append(f"cpus {settings.cpus}")
    if settings.fifo_priority is not None:
        if not hasattr(os, "sched_setscheduler"):
            raise RealtimeError(f"realtime.stages.{stage}.fifo_priority: SCHED_FIFO is not available on this OS")
        try:
            _each_thread(pid, lambda tid: os.sched_setscheduler(tid, os.SCHED_FIFO,
                                                                os.sched_param(settings.fifo_priority)))
        except PermissionError:
            raise RealtimeError(
                f"realtime.stages.{stage}.fifo_priority: the OS refused SCHED_FIFO for this user (needs "
                "CAP_SYS_NICE or an rtprio limit, e.g. LimitRTPRIO= in the systemd unit); remove the "
                "setting or grant it") from None
        applied.append(f"SCHED_FIFO {settings.fifo_priority}")
    return applied

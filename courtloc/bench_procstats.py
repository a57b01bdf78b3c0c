"""CPU time and proportional memory (PSS) of the processes a bench started, read from /proc.

A sampler thread notes, once a second, every child of this process that is a stage or a router
(`courtloc run NAME` / `courtloc router`): CPU seconds (utime + stime) and PSS. CPU per frame is the
difference between the first sample after the warm-up and the last one, over the frames in between.
Linux only; elsewhere the report says why it is empty.
"""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from courtloc.router_process import ROUTER_MODULE
from courtloc.stage_cli import SIM_CAMERA_MODULE

_PROC = Path("/proc")
_TICKS = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


@dataclass
class _Sample:
    pid: int
    at: float
    cpu_s: float
    pss_kb: int


@dataclass
class ProcessSampler:
    warmup_s: float = 3.0
    period_s: float = 1.0
    first: dict[str, _Sample] = field(default_factory=dict)
    last: dict[str, _Sample] = field(default_factory=dict)
    peak_pss_kb: dict[str, int] = field(default_factory=dict)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _started: float = 0.0

    def start(self) -> ProcessSampler:
        self._started = time.monotonic()
        self._thread = threading.Thread(target=self._loop, name="proc-sampler", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            now = time.monotonic()
            for role, pid in child_processes(os.getpid()).items():
                sample = _read(pid, now)
                if sample is None:
                    continue
                if now - self._started >= self.warmup_s:
                    if self.first.get(role, sample).pid != sample.pid:  # restarted: count the new process
                        del self.first[role]
                    self.first.setdefault(role, sample)
                    self.last[role] = sample
                self.peak_pss_kb[role] = max(self.peak_pss_kb.get(role, 0), sample.pss_kb)

    def report(self, frames_per_s: float) -> dict[str, object]:
        """Per role: CPU ms per frame (at `frames_per_s`), CPU % of one core, last PSS MB."""
        roles: dict[str, dict[str, float]] = {}
        for role, last in self.last.items():
            first = self.first[role]
            span = last.at - first.at
            if span <= 0:
                continue
            frames = span * frames_per_s
            roles[role] = {
                "cpu_ms_per_frame": round((last.cpu_s - first.cpu_s) * 1e3 / frames, 3) if frames else 0.0,
                "cpu_percent": round((last.cpu_s - first.cpu_s) / span * 100, 1),
                "pss_mb": round(last.pss_kb / 1024, 1),
            }
        return {"processes": roles,
                "note": "" if roles else "no /proc samples (not Linux, or the run was shorter than the warm-up)"}


STAGE_MODULE_PREFIX = "courtloc.services."


def stage_of_argv(argv: list[str]) -> str | None:
    """A stage runs as its own entry point, `python -m courtloc.services.<stage>`; a simulated camera as the
    twin's camera stage (SIM_CAMERA_MODULE)."""
    for arg in argv:
        if arg == SIM_CAMERA_MODULE:
            return "camera"
        if arg.startswith(STAGE_MODULE_PREFIX):
            return arg.rsplit(".", 1)[1]
    return None


def child_processes(parent: int) -> dict[str, int]:
    """The launcher's children by role: 'router' or the stage name (from their command lines)."""
    found: dict[str, int] = {}
    for entry in _PROC.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            argv = [a.decode() for a in (entry / "cmdline").read_bytes().split(b"\0") if a]
        except OSError:
            continue  # exited meanwhile
        if int(stat.rsplit(")", 1)[1].split()[1]) != parent:
            continue
        stage = stage_of_argv(argv)
        if stage is not None:
            found[stage] = int(entry.name)
        elif ROUTER_MODULE in argv or "router" in argv:  # `courtloc router` becomes ROUTER_MODULE at once
            found["router"] = int(entry.name)
    return found


def pss_kb(pid: int) -> int | None:
    """Proportional set size: a page shared by n processes (libraries, shared-memory frames) counts 1/n."""
    try:
        rollup = (_PROC / str(pid) / "smaps_rollup").read_text()
    except OSError:
        return None
    return next((int(line.split()[1]) for line in rollup.splitlines() if line.startswith("Pss:")), None)


def _read(pid: int, now: float) -> _Sample | None:
    try:
        fields = (_PROC / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    pss = pss_kb(pid)
    if pss is None:
        return None
    # fields[0] is the state (field 3 of stat): utime and stime are stat fields 14 and 15
    cpu_s = (int(fields[11]) + int(fields[12])) / _TICKS
    return _Sample(pid, now, cpu_s, pss)

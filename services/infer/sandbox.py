"""Validating a candidate model in a child process whose memory and time are bounded.

A candidate is untrusted until validated: its graph may allocate gigabytes when onnxruntime loads it
(constant folding) or runs it, or never finish. So every check of `validation.validate_candidate` runs in
a fresh interpreter (`python -m courtloc.services.infer.sandbox`): it imports what validation needs,
then caps its own address space at what it uses plus `validation_memory_mb` (RLIMIT_AS; allocations
past it fail inside the child) and its CPU time, lowers its priority, and answers one JSON line. The
infer service waits for it on its control thread, never on the thread that serves frames, and kills
it after `validation_timeout_s`. A child that dies answers nothing: the candidate is refused.
"""
from __future__ import annotations

import ctypes
import logging
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import onnxruntime
from onnx import TensorProto, helper
from pydantic import BaseModel, ConfigDict

from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.validation import ModelRefused, available_providers, validate_candidate

log = logging.getLogger(__name__)
_MEMORY_WORDS = ("bad_alloc", "memoryerror", "failed to allocate", "cannot allocate", "out of memory",
                 "std::length_error")


class SandboxRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    folder: Path
    config: InferConfig
    pushed: bool = False


class SandboxReport(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ok: bool
    reason: str
    peak_rss_mb: float = 0.0


def validate_in_child(folder: Path, config: InferConfig, pushed: bool) -> str:
    """The child's summary of a candidate that passed; ModelRefused with the reason otherwise."""
    request = SandboxRequest(folder=Path(folder).resolve(), config=config, pushed=pushed)
    # One malloc arena per thread would reserve 64 MB of address space each, counted against the limit.
    env = {**os.environ, "MALLOC_ARENA_MAX": "2", "OMP_NUM_THREADS": "1"}
    child = subprocess.Popen([sys.executable, "-m", "courtloc.services.infer.sandbox", str(os.getpid())], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    log.info("validating %s in child pid %d (limits %g MB, %g s)", Path(folder).name, child.pid,
             config.validation_memory_mb, config.validation_timeout_s)
    try:
        out, err = child.communicate(request.model_dump_json(), timeout=config.validation_timeout_s)
    except subprocess.TimeoutExpired:
        child.kill()
        child.communicate()
        raise ModelRefused(f"validation did not finish within {config.validation_timeout_s:g} s "
                           "(validation_timeout_s): candidate refused") from None
    lines = out.strip().splitlines()
    try:
        report = SandboxReport.model_validate_json(lines[-1]) if lines else None
    except ValueError:
        report = None
    if report is None:
        died = (f"killed by signal {-child.returncode}" if child.returncode < 0 else f"exit code {child.returncode}")
        last = err.strip().splitlines()[-1:] or ["no output"]
        raise ModelRefused(f"validation process died ({died}; limit {config.validation_memory_mb:g} MB): "
                           f"{last[0][:300]}")
    if not report.ok:
        raise ModelRefused(report.reason)
    return f"{report.reason}; peak RSS {report.peak_rss_mb:.0f} MB"


def _memory_limited(reason: str) -> bool:
    lowered = reason.lower()
    return any(word in lowered for word in _MEMORY_WORDS)


def _die_with_parent(parent: int) -> None:
    """SIGKILL when the infer stage dies (PR_SET_PDEATHSIG), so a killed stage leaves no validation running."""

    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the call
        os._exit(1)


def _limit_self(config: InferConfig) -> None:
    """Cap this process: its address space now plus the budget, CPU seconds, and a lower priority."""
    with open("/proc/self/status", encoding="ascii") as status:
        vm_kb = next(int(line.split()[1]) for line in status if line.startswith("VmSize:"))
    cap = vm_kb * 1024 + int(config.validation_memory_mb * 2**20)
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    cpu = int(config.validation_timeout_s) + 5  # a backstop if the parent is gone: the parent's deadline rules
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 5))
    os.nice(10)  # the stage's own threads keep the CPU they need for frames


def _preload(config: InferConfig) -> None:
    """The execution providers started before the cap (everything validation imports is imported with this
    module): the limit is on the candidate, not on our libraries (a CUDA or TensorRT provider reserves its
    address space when its first session opens)."""
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "warm",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    session = onnxruntime.InferenceSession(model.SerializeToString(),
                                           providers=available_providers(config.providers))
    session.run(None, {"x": np.zeros(1, np.float32)})


def main() -> int:
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    _die_with_parent(int(sys.argv[1]))
    request = SandboxRequest.model_validate_json(sys.stdin.read())
    _preload(request.config)
    _limit_self(request.config)
    try:
        report = SandboxReport(ok=True, reason=validate_candidate(request.folder, request.config, request.pushed))
    except ModelRefused as exc:
        report = SandboxReport(ok=False, reason=str(exc))
    except MemoryError:
        report = SandboxReport(ok=False, reason="MemoryError")
    if not report.ok and _memory_limited(report.reason):
        report.reason = (f"memory: the candidate needs more than the validation limit of "
                         f"{request.config.validation_memory_mb:g} MB (validation_memory_mb): {report.reason[:300]}")
    report.peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    sys.stdout.write(report.model_dump_json() + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""`courtloc doctor`: what this machine has, and what a deployment file needs from it.

Run it on the Jetson after an install (docs/jetson.md) and on the pit laptop. It exits non-zero when the
deployment cannot run here (e.g. the camera is a GStreamer pipeline and this OpenCV has no GStreamer, or
two onnxruntime distributions shadow each other); slower-but-working fallbacks are warnings.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
from dataclasses import asdict, dataclass
from importlib import metadata
from importlib.machinery import PathFinder
from pathlib import Path
from typing import Any, Literal

import zenoh
from cv2 import videoio_registry

from courtloc.cliargs import add_json_argument, json_to_stdout
from courtloc.native_report import KERNELS as NATIVE_KERNELS
from courtloc.services.deployment import load_deployment

KERNELS = {label: module for label, module, _, _ in NATIVE_KERNELS}
ORT_DISTRIBUTIONS = ("onnxruntime", "onnxruntime-gpu")
# optional extras and what they enable (pit laptop tools)
EXTRAS = {"foxglove-sdk": "courtloc foxglove", "rosbags": "courtloc export rosbag2 / ros bridge",
          "torch": "courtloc train"}
_PROVIDER_NAMES = {"tensorrt": "TensorrtExecutionProvider", "cuda": "CUDAExecutionProvider",
                   "cpu": "CPUExecutionProvider"}
Level = Literal["ok", "warn", "fail"]


@dataclass(frozen=True)
class Need:
    level: Level
    what: str
    detail: str


def _jetson_model() -> str | None:
    model = Path("/proc/device-tree/model")
    release = Path("/etc/nv_tegra_release")
    if model.is_file() and "jetson" in model.read_bytes().decode(errors="replace").lower():
        return model.read_bytes().decode(errors="replace").strip("\x00\n ")
    if release.is_file():
        return release.read_text(errors="replace").splitlines()[0]
    return None


def opencv_facts() -> dict[str, Any]:
    try:
        import cv2  # probed: a broken install is reported, not fatal
    except ImportError as exc:
        return {"installed": False, "error": str(exc)}

    build = cv2.getBuildInformation()
    # another cv2 later on sys.path (JetPack's, under a venv with system site packages) is shadowed by this one

    loaded = Path(cv2.__file__).resolve().parent
    shadowed = sorted({str(Path(spec.origin).resolve().parent) for entry in sys.path if entry
                       for spec in [PathFinder.find_spec("cv2", [entry])]
                       if spec is not None and spec.origin and Path(spec.origin).resolve().parent != loaded})
    found = re.search(r"^\s*GStreamer:\s*(.+)$", build, re.MULTILINE)
    gst_line = found.group(1).strip() if found else "not listed"
    origin = str(Path(cv2.__file__).resolve())
    return {"installed": True, "version": cv2.__version__, "module": origin,
            "from": "system (dist-packages)" if "dist-packages" in origin else "pip (site-packages)",
            "gstreamer": gst_line.upper().startswith("YES") and bool(videoio_registry.hasBackend(cv2.CAP_GSTREAMER)),
            "gstreamer_build": gst_line,
            "video_backends": sorted({videoio_registry.getBackendName(b) for b in videoio_registry.getBackends()
                                      if videoio_registry.hasBackend(b)}),
            "cuda_devices": int(cv2.cuda.getCudaEnabledDeviceCount()) if hasattr(cv2, "cuda") else 0,
            "shadowed": shadowed}


def onnxruntime_facts() -> dict[str, Any]:
    distributions = {}
    for name in ORT_DISTRIBUTIONS:
        try:
            distributions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    try:
        import onnxruntime  # probed: a broken install is reported, not fatal
    except ImportError as exc:
        return {"installed": False, "error": str(exc), "distributions": distributions}
    return {"installed": True, "version": onnxruntime.__version__, "providers": onnxruntime.get_available_providers(),
            "distributions": distributions}


def extras_facts() -> dict[str, str | None]:
    found: dict[str, str | None] = {}
    for name in EXTRAS:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = None
    return found


def kernel_facts() -> dict[str, bool]:
    built = {}
    for label, module in KERNELS.items():
        try:
            importlib.import_module(module)
            built[label] = True
        except ImportError:
            built[label] = False
    return built


def shm_facts() -> dict[str, Any]:
    shm = Path("/dev/shm")
    facts: dict[str, Any] = {"path": str(shm), "present": shm.is_dir()}
    if shm.is_dir():
        stat = os.statvfs(shm)
        facts.update(writable=os.access(shm, os.W_OK), free_mb=round(stat.f_bavail * stat.f_frsize / 1e6, 1))

    facts["zenoh_shm_api"] = hasattr(zenoh, "shm")
    return facts


def _run(argv: list[str]) -> str | None:
    if shutil.which(argv[0]) is None:
        return None
    try:
        return subprocess.run(argv, capture_output=True, text=True, timeout=3, check=False).stdout
    except (OSError, subprocess.TimeoutExpired):
        return None


def clock_facts() -> dict[str, Any]:
    """Whether the wall clock is disciplined (NTP/PTP): stamps compared across hosts depend on it."""
    answer = _run(["timedatectl", "show", "-p", "NTPSynchronized", "--value"])
    if answer and answer.strip() in ("yes", "no"):
        return {"synchronized": answer.strip() == "yes", "source": "timedatectl"}
    tracking = _run(["chronyc", "-n", "tracking"])
    if tracking and "Leap status" in tracking:
        return {"synchronized": "Normal" in tracking.split("Leap status", 1)[1].splitlines()[0], "source": "chronyc"}
    if Path("/run/systemd/timesync/synchronized").exists():
        return {"synchronized": True, "source": "systemd-timesyncd"}
    return {"synchronized": None, "source": "unknown (no timedatectl, chronyc or timesyncd state)"}


def machine_facts() -> dict[str, Any]:
    return {"platform": f"{platform.system()} {platform.release()} {platform.machine()}",
            "python": sys.version.split()[0], "jetson": _jetson_model(), "opencv": opencv_facts(),
            "onnxruntime": onnxruntime_facts(), "kernels": kernel_facts(), "extras": extras_facts(), "shm": shm_facts(),
            "clock": clock_facts()}


def deployment_needs(config: Any, facts: dict[str, Any]) -> list[Need]:
    """What `config` (a DeploymentConfig) needs from this machine, each with a verdict."""
    needs: list[Need] = []
    services = set(config.launcher.services)
    cv = facts["opencv"]
    if "camera" in services and config.camera.source == "device":
        device = config.camera.device.device
        if device.isdigit():
            needs.append(Need("ok" if "V4L2" in cv.get("video_backends", []) else "warn", "camera.device.device",
                              f"V4L2 index {device}: OpenCV's V4L2 backend "
                              f"{'is there' if 'V4L2' in cv.get('video_backends', []) else 'is missing'}"))
        elif cv.get("gstreamer"):
            needs.append(Need("ok", "camera.device.device", "a GStreamer pipeline; this OpenCV has GStreamer"))
        else:
            hint = (f"pip's OpenCV shadows {cv['shadowed']}: pip uninstall opencv-python-headless"
                    if cv.get("shadowed") else "use JetPack's OpenCV through a venv with --system-site-packages, "
                                               "or the v4l2loopback bridge of docs/jetson.md and a V4L2 index")
            needs.append(Need("fail", "camera.device.device",
                              f"a GStreamer pipeline, but this OpenCV ({cv.get('from', 'not installed')}) has no "
                              f"GStreamer: {hint}"))
    ort = facts["onnxruntime"]
    if len(ort.get("distributions", {})) > 1:
        needs.append(Need("fail", "onnxruntime", f"both {sorted(ort['distributions'])} are installed and shadow "
                                                 "each other: keep one (docs/jetson.md)"))
    if "infer" in services:
        available = set(ort.get("providers", []))
        for field, wanted in (("infer.providers", config.infer.providers),
                              ("infer.accelerator_providers", config.infer.accelerator_providers)):
            names = [_PROVIDER_NAMES[p] for p in wanted]
            usable = [n for n in names if n in available] or ["CPUExecutionProvider"]
            missing = [n for n in names if n not in available]
            note = f" ({missing} not installed)" if missing else ""
            needs.append(Need("warn" if missing and usable[0] != names[0] else "ok", field,
                              f"wants {names}; will use {usable[0]}{note}"))
    for label, built in facts["kernels"].items():
        needs.append(Need("ok" if built else "warn", f"{label} kernel",
                          "compiled" if built else "not built: the numpy fallback runs, several times slower "
                                                   "(reinstall with a C compiler)"))
    remote = [e for e in (*config.zenoh.connect, *config.zenoh.listen) if not re.search(r"/(127\.|localhost)", e)]
    clock = facts["clock"]
    if remote:
        level: Level = "ok" if clock["synchronized"] else "warn"
        needs.append(Need(level, "clock sync", f"endpoints {remote} cross hosts: stage latency and staleness use "
                                               f"wall clocks there; synchronized = {clock['synchronized']} "
                                               f"({clock['source']})"))
    shm = facts["shm"]
    needs.append(Need("ok" if shm.get("writable") else "warn", "shared memory",
                      f"{shm['path']} {'writable' if shm.get('writable') else 'missing or read-only'}, "
                      f"{shm.get('free_mb', 0)} MB free"))
    if "shooter_bridge" in services:
        port = config.shooter_bridge.link.port
        needs.append(Need("ok" if Path(port).exists() else "warn", "shooter_bridge.link.port",
                          f"{port} {'present' if Path(port).exists() else 'not present (MCU unplugged?)'}"))
    return needs


def register(sub: argparse._SubParsersAction) -> None:
    doctor = sub.add_parser("doctor", help="what this machine has (OpenCV, onnxruntime, kernels, SHM, clock) and "
                                           "what a deployment needs from it")
    doctor.add_argument("--config", type=Path, default=None, help="deployment TOML (default: built-in)")
    add_json_argument(doctor, "the machine's facts and the deployment's needs")
    doctor.set_defaults(func=run)


def _report(facts: dict[str, Any], needs: list[Need], config_name: str) -> str:
    cv, ort, shm, clock = facts["opencv"], facts["onnxruntime"], facts["shm"], facts["clock"]
    lines = ["This machine:",
             f"  platform      {facts['platform']}, Python {facts['python']}, Jetson: {facts['jetson'] or 'no'}",
             (f"  OpenCV        {cv['version']} from {cv['from']}; GStreamer: {cv['gstreamer_build']}; "
              f"video backends: {', '.join(cv['video_backends'])}"
              + (f"; shadows the cv2 in {', '.join(cv['shadowed'])}" if cv["shadowed"] else "") if cv["installed"] else
              f"  OpenCV        not importable: {cv['error']}"),
             (f"  onnxruntime   {ort['version']} ({', '.join(f'{k} {v}' for k, v in ort['distributions'].items())}); "
              f"providers: {', '.join(ort['providers'])}" if ort["installed"] else
              f"  onnxruntime   not importable: {ort['error']}"),
             "  kernels       " + ", ".join(f"{k}: {'compiled' if v else 'numpy fallback'}"
                                          for k, v in facts["kernels"].items()),
             f"  shared memory {shm['path']}: {'writable' if shm.get('writable') else 'unusable'}, "
             f"{shm.get('free_mb', 0)} MB free; zenoh SHM API: {'yes' if shm['zenoh_shm_api'] else 'no'}",
             f"  clock sync    {clock['synchronized']} ({clock['source']})",
             "  extras        " + ", ".join(f"{k} {v or 'not installed'} ({EXTRAS[k]})"
                                          for k, v in facts["extras"].items()),
             f"What {config_name} needs:"]
    marks = {"ok": "ok  ", "warn": "warn", "fail": "FAIL"}
    lines += [f"  [{marks[n.level]}] {n.what}: {n.detail}" for n in needs]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    config = load_deployment(args.config)  # a bad file or field raises, named (courtloc.cli: one line)
    facts = machine_facts()
    needs = deployment_needs(config, facts)
    if args.json is not None:
        args.json.write_text(json.dumps({"machine": facts, "needs": [asdict(n) for n in needs]}))
    if not json_to_stdout(args.json):
        print(_report(facts, needs, str(args.config) if args.config else "the built-in deployment"))
    return 1 if any(n.level == "fail" for n in needs) else 0

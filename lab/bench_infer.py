"""per-frame latency and peak RSS of the servable models, and the latency spike of a hot swap

`courtloc bench infer --json OUT [--paper FILE|DIR] [--frames N]` measures, side by side in one run:
- every model as the infer service runs it (`predict` on radial-scan hits: the paper network's input
  built from the hits + onnxruntime; the geometric package's network + fit, tracking from its last pose),
  each in its own process so its peak RSS (ru_maxrss of that child) is its own;
- the bundled default serving a 30 fps stream while another version is validated and swapped in by the
  service's own control path: per-frame latency (tick to pose) during the swap vs before it.
Inputs are the seed-gazebo twin rendered along a drive and run through the real preprocess pipeline.
Writes {"models": [{"name", "form", "latency_ms_p50", "latency_ms_p99", "peak_rss_mb"}, ...],
"swap_spike_ms": ...}; swap_spike_ms = slowest frame during the swap minus the median frame before it.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from courtloc.cliargs import add_json_argument, positive_int
from courtloc.common.bus import ZenohConfig
from courtloc.common.control import Activate, ModelRequest
from courtloc.common.messages import Edges, Header
from courtloc.common.payloads import hits_to_bytes
from courtloc.localizer.manifest import PAPER_KINDS, read_manifest, write_manifest
from courtloc.localizer.predictor import load_predictor
from courtloc.models import bundled_package
from courtloc.scan.config import PreprocessConfig
from courtloc.scan.preprocessor import Preprocessor
from courtloc.services.infer.config import InferConfig
from courtloc.services.infer.service import InferService
from courtloc.services.infer.validation import available_providers
from courtloc.sim.render import Renderer
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

SWAP_FPS = 30.0
SWAP_LEAD_FRAMES = 60  # frames served before the swap starts: the "before" distribution


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_json_argument(parser, "the result", required=True)
    parser.add_argument("--paper", type=Path, default=None,
                        help="a trained paper model (.onnx, dense or sparse) or a folder of them; "
                             "without it the paper rows are omitted")
    parser.add_argument("--frames", type=positive_int, default=100, help="frames timed per model")
    parser.add_argument("--threads", type=positive_int, default=1, help="onnxruntime intra-op threads")
    parser.add_argument("--worker", choices=["model", "swap"], default=None, help=argparse.SUPPRESS)
    parser.add_argument("--model", type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--hits", type=Path, default=None, help=argparse.SUPPRESS)


def drive_poses(n: int) -> list[tuple[float, float, float]]:
    """A drive there and back across the court's +x half, 5 cm between frames (a tracking model keeps up)."""
    half = max(2, (n + 1) // 2)
    out = [(2.0 + 1.5 * t, -1.5 + 2.0 * t, 0.4 - 0.6 * t) for t in np.linspace(0.0, 1.0, half)]
    return (out + out[::-1])[:n]


def _render_hits(n: int, out: Path) -> None:
    camera = load_camera("seed-gazebo")
    renderer = Renderer(load_court("seed-gazebo"), camera)
    pre = Preprocessor(PreprocessConfig(frame_width=camera.width, frame_height=camera.height))
    hits = [pre.process(renderer.render(pose)) for pose in drive_poses(n)]
    np.savez(out, width=camera.width, height=camera.height, *hits)


def _load_hits(path: Path) -> tuple[list[np.ndarray], int, int]:
    data = np.load(path)
    frames = [data[f"arr_{i}"] for i in range(len(data.files) - 2)]
    return frames, int(data["width"]), int(data["height"])


def peak_rss_mb() -> float:
    """This process's own peak resident set: VmHWM (per address space, so it starts afresh at exec; a
    child's ru_maxrss can carry its parent's peak over the fork). ru_maxrss where /proc is absent."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _worker_model(args: argparse.Namespace) -> int:
    frames, width, height = _load_hits(args.hits)
    predictor = load_predictor(args.model, providers=available_providers(["tensorrt", "cuda", "cpu"]),
                               threads=args.threads)
    previous = None
    warm = predictor.predict(frames[0], width, height)  # cold start (a tracker's global search), not timed
    if warm.valid and warm.yaw is not None:
        previous = (warm.x, warm.y, warm.yaw)
    times = []
    for hits in frames:
        start = time.perf_counter()
        pred = predictor.predict(hits, width, height, previous=previous)
        times.append(time.perf_counter() - start)
        if pred.valid and pred.yaw is not None:
            previous = (pred.x, pred.y, pred.yaw)
    ms = np.asarray(times) * 1e3
    print(json.dumps({"name": predictor.manifest.name, "form": predictor.manifest.input.kind,
                      "latency_ms_p50": float(np.percentile(ms, 50)), "latency_ms_p99": float(np.percentile(ms, 99)),
                      "peak_rss_mb": peak_rss_mb()}))
    return 0


def _worker_swap(args: argparse.Namespace) -> int:
    """The service's own objects (no bus): a 30 fps frame thread, and an activation on a control thread."""

    frames, width, height = _load_hits(args.hits)
    with tempfile.TemporaryDirectory() as tmp:
        service = InferService("bench", ZenohConfig(), InferConfig(store=Path(tmp) / "store", threads=args.threads))
        service.active = service._load_active()
        candidate = Path(tmp) / "candidate"
        shutil.copytree(bundled_package(), candidate)
        write_manifest(candidate / "model.onnx", read_manifest(candidate / "model.onnx").model_copy(
            update={"name": "candidate"}))
        stored = service.store.add_folder(candidate, "candidate")
        edges = [Edges(header=Header.now("bench", i, "bench").forwarded("preprocess", valid=True), width=width, height=height, crop_top=200,
                       n_hits=len(h), hits=hits_to_bytes(h)) for i, h in enumerate(frames)]

        window: dict[str, float] = {}

        def swap() -> None:
            window["start"] = time.perf_counter()
            request = ModelRequest(body=Activate(name="candidate", version=stored.ref.version))
            reply = service._control.handle(request)
            window["end"] = time.perf_counter()
            window["ok"] = float(reply.ok)

        rows: list[tuple[float, float]] = []  # (tick time, tick-to-pose latency)
        period = 1.0 / SWAP_FPS
        tick = time.perf_counter()
        swapper = threading.Thread(target=swap)
        i, frames_after = 0, 0
        while frames_after < SWAP_LEAD_FRAMES // 2:  # until a while after the swap is done
            if i == SWAP_LEAD_FRAMES:
                swapper.start()
            elif i > SWAP_LEAD_FRAMES and not swapper.is_alive():
                frames_after += 1
            tick += period
            time.sleep(max(0.0, tick - time.perf_counter()))  # the camera's cadence
            message = edges[i % len(edges)]
            service.make_pose(service.active, message, frames[i % len(frames)], True, service.tracker)
            rows.append((tick, time.perf_counter() - tick))
            i += 1
        swapper.join()
    before = [lat for t, lat in rows if t < window["start"]]
    during = [lat for t, lat in rows if window["start"] <= t <= window["end"]] or [0.0]
    print(json.dumps({"ok": bool(window["ok"]), "swap_s": window["end"] - window["start"],
                      "before_ms_p50": float(np.median(before) * 1e3), "during_ms_max": float(max(during) * 1e3),
                      "during_ms_p50": float(np.median(during) * 1e3), "frames_during": len(during),
                      "served_by": service.active.ref.name}))
    return 0


def _child(args: argparse.Namespace, extra: list[str]) -> dict:
    """Run a worker (its own process, so what it loads is measured alone); its JSON line."""
    cmd = [sys.executable, "-c", "from courtloc.cli import main; main()", "bench", "infer", "--json", os.devnull,
           "--threads", str(args.threads), "--hits", str(args.hits), *extra]
    done = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
    if done.returncode:
        raise SystemExit(f"benchmark worker {extra} failed (exit {done.returncode})")
    return json.loads(done.stdout.strip().splitlines()[-1])


def paper_models(path: Path) -> list[Path]:
    files = sorted(path.glob("*.onnx")) if path.is_dir() else [path]
    found = [f for f in files if read_manifest(f).input.kind in PAPER_KINDS]
    if not found:
        raise SystemExit(f"no paper model (dense_image / sparse_hits ONNX) at {path}")
    return sorted(found, key=lambda f: read_manifest(f).input.kind)  # dense first


def run(args: argparse.Namespace) -> int:
    if args.worker == "model":
        return _worker_model(args)
    if args.worker == "swap":
        return _worker_swap(args)

    models = [*(paper_models(args.paper) if args.paper else []), bundled_package()]
    if args.paper is None:
        print("no --paper: the paper network's dense and sparse rows are omitted", file=sys.stderr)
    with tempfile.TemporaryDirectory() as tmp:
        args.hits = Path(tmp) / "hits.npz"
        _render_hits(max(args.frames, 2), args.hits)
        rows = []
        for model in models:
            row = _child(args, ["--worker", "model", "--model", str(model)])
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
        swap = _child(args, ["--worker", "swap"])
    print(f"swap: {json.dumps(swap)}", file=sys.stderr)
    if not swap["ok"]:
        raise SystemExit("the swap in the benchmark was refused")
    result = {"models": [{k: row[k] for k in ("name", "form", "latency_ms_p50", "latency_ms_p99", "peak_rss_mb")}
                         for row in rows],
              "swap_spike_ms": swap["during_ms_max"] - swap["before_ms_p50"]}
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))
    return 0

"""fuzz: replay the hostile catalogue and random mutations of valid messages against a running chain

Starts `courtloc up` on a free loopback port (its own router and stages, separate processes), waits
for the first valid pose, then for `--seconds` publishes hostile payloads into every input topic and
the model-control queryable: the catalogue of issue 16 (future stamps, decode bombs, PNG as JPEG,
stamp and hit floods, oversized chunks and names, coerced fields, frames of the wrong size) and
random mutations of messages captured from the live bus. It reports crashes and restarts, rejections
by reason per stage, stale counts, seconds without a valid pose, hostile inputs that came out valid
(poses or SET_RPM), log volume and peak RSS per stage. Every loop is bounded; it stops by itself.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import cv2
import msgpack
import numpy as np
import zenoh

from courtloc.bench_procstats import child_processes
from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout, nonnegative_float, positive_float
from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.limits import MAX_CHUNK_BYTES
from courtloc.common.messages import Header, Health, Pose, ShotSolution
from courtloc.common.services_table import (
    CONTROLS,
    SERVICES,
    TOPICS,
    all_health_key,
    all_liveliness_key,
    service_of_liveliness_key,
)
from courtloc.common.signals import stop_on_signals

HOSTILE_SEQ = 1 << 40  # hostile messages that must never come out valid carry seq >= this
UNCHECKED_SEQ = 1 << 39  # mutations that may still be legitimate messages (not counted either way)
HEAVY_BYTES = 1 << 20  # payloads above this are sent at most once per HEAVY_PERIOD_S
HEAVY_PERIOD_S = 2.0
WARMUP_TIMEOUT_S = 180.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seconds", type=positive_float, default=30.0,
                        help="how long to fuzz (after the chain is up)")
    add_json_argument(parser, "the report (default: printed to standard output)")
    parser.add_argument("--rate-hz", type=nonnegative_float, default=60.0,
                        help="hostile payloads per second, all topics (0: a baseline run that sends none)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--services", nargs="+", default=None, choices=list(SERVICES), metavar="STAGE",
                        help=f"stages to run (default: {' '.join(SERVICES)})")
    parser.add_argument("--fps", type=positive_float, default=30.0, help="the sim camera's frame rate")


@dataclass(frozen=True)
class Probe:
    name: str
    path: str  # a topic path, or the control path "infer/model"
    payload: bytes
    must_not_be_valid: bool = False  # if its seq comes out valid, the chain trusted hostile input
    # Stamped relative to the moment it is sent (a "+10 s" stamp made once would be fresh 10 s later)
    restamp: Callable[[], bytes] | None = None

    def bytes_now(self) -> bytes:
        return self.restamp() if self.restamp is not None else self.payload


def _header(robot_id: str, seq: int, ahead_s: float = 0.0, valid: bool = True) -> dict[str, Any]:
    header = Header.now(robot_id, seq, "fuzz").model_dump()
    shift = int(ahead_s * 1e9)
    header.update(capture_mono_ns=header["capture_mono_ns"] + shift, capture_wall_ns=header["capture_wall_ns"] + shift,
                  valid=valid)
    return header


def _pack(message: dict[str, Any]) -> bytes:
    return msgpack.packb(message, use_bin_type=True)


def _bomb_jpeg(declared: int = 16000) -> bytes:
    """A tiny valid JPEG whose frame header declares `declared` x `declared` pixels."""

    ok, jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    data = jpeg.tobytes()
    sof = data.index(b"\xff\xc0")
    return data[:sof + 5] + declared.to_bytes(2, "big") * 2 + data[sof + 9:]


def hostile_catalogue(robot_id: str, captured: dict[str, dict[str, Any]], next_seq: Callable[[], int]) -> list[Probe]:
    """The issue's hostile inputs; `captured` holds a valid decoded message per topic when one was seen."""

    probes: list[Probe] = []
    pose = captured.get("infer/pose") or {"x": 2.0, "y": 0.0, "yaw": 0.0, "quality": 1.0, "model_name": "m",
                                          "model_version": 1, "infer_ms": 0.1, "reason": ""}
    frame = captured.get("camera/frame")
    edges = captured.get("preprocess/edges")

    def with_header(message: dict[str, Any], ahead_s: float = 0.0, **header: Any) -> tuple[dict[str, Any], int]:
        seq = next_seq()
        return {**message, "header": {**_header(robot_id, seq, ahead_s), **header}}, seq

    def timed(name: str, path: str, message: dict[str, Any], ahead_s: float = 0.0, **header: Any) -> Probe:
        """A probe whose header is stamped `ahead_s` from the moment it is sent (so only what it is
        meant to test is wrong with it: a stamp made once would drift out of freshness)."""
        stamped, seq = with_header(message, ahead_s, **header)

        def restamp() -> bytes:
            return _pack({**message, "header": {**_header(robot_id, seq, ahead_s), **header}})

        return Probe(name, path, _pack(stamped), True, restamp)

    # 4. time: stamps from the future
    for ahead in (10.0, 1000.0):
        for path, message in (("infer/pose", pose), ("camera/frame", frame), ("preprocess/edges", edges)):
            if message is not None:
                probes.append(timed(f"future_{int(ahead)}s:{path}", path, message, ahead))
    # 6. decode bombs and the wrong format under "jpeg"
    frame_fields = {"width": 640, "height": 480, "encoding": "jpeg"}
    probes.append(timed("decode_bomb", "camera/frame", {**frame_fields, "data": _bomb_jpeg()}))
    probes.append(timed("declared_16000", "camera/frame",
                        {"width": 16000, "height": 16000, "encoding": "jpeg", "data": _bomb_jpeg()}))
    ok, png = cv2.imencode(".png", np.zeros((480, 640, 3), np.uint8))
    probes.append(timed("png_as_jpeg", "camera/frame", {**frame_fields, "data": png.tobytes()}))
    # 7. sizes: stamps, hits, chunks, names
    stamp = {"stage": "s", "mono_ns": 0, "wall_ns": 0, "host": "h"}
    flood, _ = with_header({**frame_fields, "data": b""})
    flood["header"]["stamps"] = [stamp] * 1_000_000
    probes.append(Probe("stamps_1e6", "camera/frame", _pack(flood), True))  # 35 MB: zenoh drops it (bus bound)
    # Over the topic's limit but under the bus bound (services_table.MAX_BUS_MESSAGE_BYTES): it reaches the
    # stage, whose own size check refuses it as too_large; bigger ones never leave zenoh, uncounted.
    probes.append(Probe("frame_over_limit", "camera/frame", b"\0" * (TOPICS["camera/frame"].max_bytes + 1)))
    probes.append(Probe("hits_1e6", "preprocess/edges",
                        _pack(with_header({"width": 640, "height": 480, "crop_top": 0, "n_hits": 1_000_000,
                                           "hits": b"\0" * 8_000_000})[0]), True))
    probes.append(Probe("robot_id_5MB", "infer/pose", _pack(with_header(pose, robot_id="r" * 5_000_000)[0]), True))
    probes.append(timed("robot_id_1kB", "infer/pose", pose, robot_id="r" * 1000))
    probes.append(Probe("chunk_50MB", "infer/model", b"\0" * (50 * 2**20)))
    probes.append(Probe("chunk_over_limit", "infer/model", _pack({"schema_version": 1, "body": {
        "op": "push_chunk", "upload_id": "u", "file_index": 0, "offset": 0, "data": b"\0" * (MAX_CHUNK_BYTES + 1)}})))
    probes.append(Probe("bad_file_name", "infer/model", _pack({"schema_version": 1, "body": {
        "op": "push_begin", "files": [{"path": "../escape", "size": 1, "sha256": "0" * 64}]}})))
    # 8. inputs that make a handler raise: edges of a frame size the model was not made for
    if edges is not None:
        probes.append(timed("edges_wrong_frame_size", "preprocess/edges", {**edges, "width": 1, "height": 1}))
    # 13. coerced fields
    probes.append(timed("valid_yes", "infer/pose", pose, valid="yes"))
    probes.append(timed("width_text", "camera/frame", {**frame_fields, "width": "640", "data": _bomb_jpeg(8)}))
    probes.append(Probe("seq_text", "preprocess/edges", _pack({**(edges or {}), "header": {
        **_header(robot_id, 0), "seq": "640"}}), True))
    probes.append(Probe("noise", "camera/frame", os.urandom(256)))
    return probes


_ODD_VALUES: list[Any] = [None, "yes", "640", -1, 2**63, -2**63, 1e308, math.nan, math.inf, [], {}, b"\0" * 64,
                          "x" * 1000, True, [None] * 100]


def _leaves(node: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(node, dict):
        return [p for k, v in node.items() for p in _leaves(v, (*path, k))] or [path]
    if isinstance(node, list) and node:
        return [p for i, v in enumerate(node) for p in _leaves(v, (*path, i))]
    return [path]


def _set(node: Any, path: tuple, value: Any) -> None:
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value


def mutate(message: dict[str, Any], robot_id: str, rng: random.Random,
           seq_of: Callable[[bool], int]) -> tuple[bytes, bool]:
    """A random mutation of a valid decoded message; True when the result must never come out valid.
    `seq_of(must_not_be_valid)` numbers it (a registered seq only for the ones that are checked)."""
    message = msgpack.unpackb(_pack(message), raw=False)  # a deep copy
    kind = rng.randrange(5)
    strict = kind == 1 and isinstance(message.get("header"), dict)
    if isinstance(message.get("header"), dict):
        # stamped now: a captured message is old by the time it is mutated, and a stale one would stop
        # at the freshness check instead of reaching the code the mutation is meant for
        message["header"].update(_header(robot_id, seq_of(strict), valid=bool(message["header"].get("valid"))))
    if kind == 0:  # one field of an unexpected type or value
        path = rng.choice(_leaves(message))
        if path:
            _set(message, path, rng.choice(_ODD_VALUES))
        return _pack(message), False
    if kind == 1:  # time shifted beyond any freshness budget, either way
        if strict:
            shift = rng.choice([-1, 1]) * rng.uniform(1.0, 1000.0)
            message["header"].update(_header(robot_id, message["header"]["seq"], shift))
        return _pack(message), strict
    data = bytearray(_pack(message))
    if kind == 2:  # flipped bytes
        for _ in range(rng.randint(1, 8)):
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        return bytes(data), False
    if kind == 3:  # truncated
        return bytes(data[:rng.randrange(len(data))]), False
    return bytes(data) + os.urandom(rng.randint(1, 64)), False  # trailing junk


@dataclass
class Observed:
    """What the fuzzer's own bus client saw; written from zenoh callbacks, read at the end."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    valid_pose_times: list[float] = field(default_factory=list)
    poses: int = 0
    wrong_valid_poses: int = 0
    wrong_set_rpm: int = 0
    solutions: int = 0
    health: dict[tuple[str, int], Any] = field(default_factory=dict)
    captured: dict[str, dict[str, Any]] = field(default_factory=dict)
    first_valid: threading.Event = field(default_factory=threading.Event)
    must_not_be_valid: set[int] = field(default_factory=set)


def _config_text(port: int, folder: Path, services: list[str], fps: float) -> str:
    endpoint = f"tcp/127.0.0.1:{port}"
    return f"""robot_id = "robot1"
[zenoh]
connect = ["{endpoint}"]
open_retry_s = 0.1
open_retry_max_s = 0.3
[router]
listen = ["{endpoint}"]
[launcher]
services = {json.dumps(services)}
[camera]
source = "sim"
fps = {fps}
[infer]
store = "{folder / 'store'}"
[shooter_bridge.link]
port = "{folder / 'no-mcu'}"
"""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _peak_rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def run(args: argparse.Namespace) -> int:
    services = args.services or list(SERVICES)
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory(prefix="courtloc-fuzz-") as tmp:
        folder = Path(tmp)
        port = _free_port()
        config = folder / "fuzz.toml"
        config.write_text(_config_text(port, folder, services, args.fps))
        logs = folder / "logs"
        logs.mkdir()
        up = subprocess.Popen([sys.executable, "-m", "courtloc", "up", "--config", str(config), "--summary-json",
                               str(folder / "summary.json")], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, env={**os.environ, "COURTLOC_LOG_DIR": str(logs)})
        stop = stop_on_signals()
        give_up = threading.Timer(60.0, stop.set)
        give_up.start()
        session = open_session(ZenohConfig(connect=[f"tcp/127.0.0.1:{port}"], open_retry_s=0.1, open_retry_max_s=0.3),
                               stop)
        give_up.cancel()
        if session is None:
            up.kill()
            raise UsageError(f"the chain's router never answered at tcp/127.0.0.1:{port} within 60 s", RUN_EXIT)
        seen = Observed()
        try:
            report = _fuzz(args, session, seen, up, services, rng, stop)
        finally:
            session.close()
            up.send_signal(signal.SIGTERM)
            try:
                up.wait(60)
            except subprocess.TimeoutExpired:
                up.kill()
                up.wait()
        summary_path = folder / "summary.json"
        summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
        report["launcher_restarts"] = summary.get("restarts", {})
        report["log"] = {p.stem: {"bytes": p.stat().st_size, "tracebacks": p.read_text(errors="replace").count("Traceback")}
                         for p in sorted(logs.glob("*.log"))}
    text = json.dumps(report, indent=2)
    if not json_to_stdout(args.json):  # `--json -`: printed once, by the write below
        print(text)
    if args.json is not None:
        args.json.write_text(text)
    return 0


def _fuzz(args: argparse.Namespace, session: zenoh.Session, seen: Observed, up: subprocess.Popen,
          services: list[str], rng: random.Random, stop: threading.Event) -> dict[str, Any]:
    robot = "robot1"
    freshness_s = TOPICS["infer/pose"].freshness_ms / 1e3

    def on_pose(sample: Any) -> None:
        try:
            pose = codec.decode(bytes(sample.payload), Pose)
        except codec.DecodeError:
            return
        if not pose.header.stamps or pose.header.stamps[-1].stage != "infer":
            return  # one of ours, published straight onto the pose topic
        with seen.lock:
            seen.poses += 1
            if pose.header.valid:
                if pose.header.seq in seen.must_not_be_valid:
                    seen.wrong_valid_poses += 1
                elif pose.header.seq < UNCHECKED_SEQ:
                    seen.valid_pose_times.append(time.monotonic())
                    seen.first_valid.set()

    def on_solution(sample: Any) -> None:
        try:
            solution = codec.decode(bytes(sample.payload), ShotSolution)
        except codec.DecodeError:
            return
        with seen.lock:
            seen.solutions += 1
            if solution.command == "SET_RPM" and solution.header.seq in seen.must_not_be_valid:
                seen.wrong_set_rpm += 1

    reports: dict[str, int] = {}
    reported = threading.Condition(seen.lock)

    def on_health(sample: Any) -> None:
        try:
            health = codec.decode(bytes(sample.payload), Health)
        except codec.DecodeError:
            return
        with reported:
            seen.health[(health.service, health.pid)] = health
            reports[health.service] = reports.get(health.service, 0) + 1
            reported.notify_all()

    def capture(path: str) -> Callable[[Any], None]:
        def on_sample(sample: Any) -> None:
            if path in seen.captured:
                return
            try:
                message = codec.decode(bytes(sample.payload), TOPICS[path].message)
            except codec.DecodeError:
                return
            with seen.lock:
                seen.captured.setdefault(path, message.model_dump())
        return on_sample

    alive: set[str] = set()
    all_alive = threading.Event()

    def on_token(sample: Any) -> None:
        service = service_of_liveliness_key(str(sample.key_expr))
        with seen.lock:
            if sample.kind == zenoh.SampleKind.PUT:
                alive.add(service)
            else:
                alive.discard(service)
            if alive >= set(services):
                all_alive.set()

    subs = [session.liveliness().declare_subscriber(all_liveliness_key(robot), on_token, history=True)]
    subs += [session.declare_subscriber(TOPICS["infer/pose"].key(robot), on_pose),
            session.declare_subscriber(TOPICS["shooter_bridge/solution"].key(robot), on_solution),
            session.declare_subscriber(all_health_key(robot), on_health)]
    subs += [session.declare_subscriber(TOPICS[p].key(robot), capture(p))
             for p in ("camera/frame", "preprocess/edges", "infer/pose")]
    warm_start = time.monotonic()
    chain_makes_poses = "infer" in services and "camera" in services
    # With no pose to wait for, until every stage is alive: a stage declares its token after its subscribers.
    ready = seen.first_valid if chain_makes_poses else all_alive
    deadline = warm_start + WARMUP_TIMEOUT_S
    while not stop.is_set() and not ready.wait(0.5) and time.monotonic() < deadline:
        if up.poll() is not None:
            break
    warmup_s = time.monotonic() - warm_start

    seq_counter = [HOSTILE_SEQ]

    def next_seq() -> int:
        seq_counter[0] += 1
        with seen.lock:
            seen.must_not_be_valid.add(seq_counter[0])
        return seq_counter[0]

    with seen.lock:
        captured = dict(seen.captured)
    catalogue = hostile_catalogue(robot, captured, next_seq)
    inputs = sorted({p for s in services for p in SERVICES[s].inputs})
    publishers = {p: session.declare_publisher(TOPICS[p].key(robot), congestion_control=zenoh.CongestionControl.BLOCK)
                  for p in inputs}
    control = CONTROLS["infer/model"]
    sent: dict[str, int] = {}
    last_heavy: dict[str, float] = {}
    pids: dict[str, set[int]] = {}
    peak_rss: dict[str, float] = {}
    period = 1.0 / args.rate_hz if args.rate_hz > 0 else math.inf
    started = time.monotonic()
    next_sample = started
    index = 0
    while not stop.is_set() and time.monotonic() - started < args.seconds:
        now = time.monotonic()
        if now >= next_sample:  # once a second: who runs, and their peak memory
            for role, pid in child_processes(up.pid).items():
                pids.setdefault(role, set()).add(pid)
                peak = _peak_rss_mb(pid)
                if peak is not None:
                    peak_rss[role] = max(peak_rss.get(role, 0.0), peak)
            next_sample = now + 1.0
        if args.rate_hz <= 0:  # baseline: the same chain and measurements, nothing hostile
            stop.wait(max(0.0, min(next_sample, started + args.seconds) - time.monotonic()))
            continue
        if index % 2 == 0 or not captured:
            probe = catalogue[(index // 2) % len(catalogue)]
        else:
            path = rng.choice(sorted(p for p in captured if p in publishers) or [inputs[0]])
            if path in captured:
                payload, strict = mutate(captured[path], robot, rng, lambda checked: next_seq() if checked
                                         else UNCHECKED_SEQ + index)
            else:
                payload, strict = os.urandom(64), False
            probe = Probe(f"mutation:{path}", path, payload, strict)
        index += 1
        kind = "mutation" if probe.name.startswith("mutation") else probe.name
        if len(probe.payload) > HEAVY_BYTES:
            if now - last_heavy.get(probe.name, -math.inf) < HEAVY_PERIOD_S:
                continue
            last_heavy[probe.name] = now
        if probe.path == control.path:
            if "infer" in services:
                session.get(control.key(robot), lambda _reply: None, payload=probe.bytes_now(), timeout=5.0)
        elif probe.path in publishers:
            publishers[probe.path].put(probe.bytes_now())
        else:
            continue
        sent[kind] = sent.get(kind, 0) + 1
        stop.wait(period)
    fuzz_s = time.monotonic() - started
    with reported:  # two more health reports from every stage, so the counts include the last payloads
        wanted = {service: reports.get(service, 0) + 2 for service in services}
        reported.wait_for(lambda: all(reports.get(s, 0) >= n for s, n in wanted.items()), timeout=10.0)
    for sub in subs:
        sub.undeclare()
    for publisher in publishers.values():
        publisher.undeclare()

    with seen.lock:
        times = [t for t in seen.valid_pose_times if started <= t <= started + fuzz_s]
        healths = list(seen.health.values())
        report_seen = (seen.poses, seen.solutions, seen.wrong_valid_poses, seen.wrong_set_rpm)
    edges_of_time = [started, *times, started + fuzz_s]
    gaps = [b - a for a, b in zip(edges_of_time, edges_of_time[1:])]
    without_pose_s = sum(max(0.0, g - freshness_s) for g in gaps) if chain_makes_poses else None
    stages: dict[str, dict[str, Any]] = {}
    for health in healths:  # several pids of one stage: a restart; their counts add up
        entry = stages.setdefault(health.service, {"pids": [], "rejected": 0, "stale": 0, "dropped": 0,
                                                   "frames_in": 0, "rejected_by_reason": {}})
        entry["pids"].append(health.pid)
        for key in ("rejected", "stale", "dropped", "frames_in"):
            entry[key] += getattr(health, key)
        for key, value in health.detail.items():
            if key.startswith("reject.") and isinstance(value, int):
                reason = key.removeprefix("reject.")
                entry["rejected_by_reason"][reason] = entry["rejected_by_reason"].get(reason, 0) + value
    restarts = {role: len(found) - 1 for role, found in pids.items()}
    return {
        "seconds": round(fuzz_s, 2), "warmup_s": round(warmup_s, 2), "rate_hz": args.rate_hz, "seed": args.seed,
        "services": services, "sent": dict(sorted(sent.items())), "sent_total": sum(sent.values()),
        "crashes": sum(restarts.values()) + (0 if up.poll() is None else 1), "restarts": restarts,
        "poses": report_seen[0], "valid_poses": len(times), "solutions": report_seen[1],
        "hostile_valid_poses": report_seen[2], "hostile_set_rpm": report_seen[3],
        "seconds_without_valid_pose": None if without_pose_s is None else round(without_pose_s, 3),
        "longest_gap_s": round(max(gaps), 3) if chain_makes_poses else None,
        "peak_rss_mb": {k: round(v, 1) for k, v in sorted(peak_rss.items())},
        "stages": stages,
    }

"""twin: pose error, validity and recovery of the real chain on the digital twin, per scenario

For each scenario (sim/scenarios.py) a router and the four stages run as separate OS
processes on loopback, supervised exactly as `courtloc up` runs them (courtloc/launcher.py), with the
camera's sim source playing the scenario. A bus client records every `infer/pose` and every
`camera/ground_truth`; the numbers (courtloc/bench_twin_metrics.py) compare each pose with the truth of
the same frame. The camera starts once the other stages are alive, so sim time 0 is a chain ready to
take frames; a run lasts `--seconds` of sim time (frames), however slowly the machine renders them.

With fusion (`--fusion`, by default both ways for the fusion scenarios) the camera's sim source also runs
the twin's MCU (sim/twin_mcu.py) on a pty, the shooter bridge opens it as its serial port and
the infer stage fuses the odometry the bridge publishes; the vision-only run configures none of it.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import queue
import socket
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from courtloc.bench_twin_frames import KeptFrame, KeptRun, write_kept
from courtloc.bench_twin_metrics import (
    Event,
    PoseSample,
    TruthSample,
    blackout_metrics,
    kidnap_metrics,
    twin_metrics,
    window_metrics,
)
from courtloc.bench_twin_views import view_judge, with_views
from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import JSON_STDOUT, add_json_argument, json_output, json_to_stdout, positive_float
from courtloc.common import codec
from courtloc.common.messages import Edges, GroundTruth, Odometry, Pose
from courtloc.common.payloads import edges_hits, edges_marks
from courtloc.common.services_table import SERVICES, TOPICS
from courtloc.launcher import Supervisor, write_effective_config
from courtloc.services.deployment import DeploymentConfig, load_deployment
from courtloc.sim.scenarios import SCENARIOS, scenario
from courtloc.sim.twin_mcu import TwinMcuConfig
from courtloc.watch import BusWatcher
from courtloc.world.camera import load_camera
from courtloc.world.court import load_court

log = logging.getLogger("courtloc.bench_twin")
STAGES_BEFORE_CAMERA = ("preprocess", "infer", "shooter_bridge")
VARIANTS = {"vision_only": "vision only", "fused": "fused"}


class BenchError(UsageError):
    """A run that cannot be measured (a stage that never came up); the message says why (courtloc.cli: one
    line, exit 1: what was asked was right, the run failed)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, RUN_EXIT)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--court", default="seed-gazebo", help="court name (world/courts) or JSON path")
    parser.add_argument("--camera", default=None, help="camera name or JSON path (default: the court's own)")
    parser.add_argument("--scenario", default=",".join(SCENARIOS),
                        help=f"comma-separated scenarios (default all: {','.join(SCENARIOS)})")
    parser.add_argument("--seconds", type=positive_float, default=30.0,
                        help="sim seconds per scenario (frames / fps)")
    parser.add_argument("--fps", type=positive_float, default=30.0, help="camera rate")
    parser.add_argument("--seed", type=int, default=1, help="trajectory and rendering seed")
    add_json_argument(parser, "the report (default: printed to standard output)")
    parser.add_argument("--config", type=Path, default=None,
                        help="deployment TOML whose stage settings to use (its bus, router, court and camera "
                             "source are replaced by the bench's)")
    parser.add_argument("--store", type=Path, default=None,
                        help="infer model store to serve from (default: a fresh one, i.e. the bundled model)")
    parser.add_argument("--tell-start", choices=("pose", "half", "none"), default="pose",
                        help="what the infer stage is told of the scenario's start ([infer] start): its pose (0.5 m, "
                             "20 deg), only its half, or nothing (default pose: what a team configures)")
    parser.add_argument("--infer", action="append", default=[], metavar="FIELD=VALUE",
                        help="set an [infer] field for every scenario (VALUE is JSON, or a plain string)")
    parser.add_argument("--logs", type=Path, default=None, help="keep the stages' logs here (default: discarded)")
    parser.add_argument("--keep-frames", type=Path, default=None, metavar="DIR",
                        help="keep each run's frames the infer stage answered (stamps, hits, marks, truth, pose) in "
                             "DIR/<scenario>[_fused].json, to replay the run in one process (bench_twin_frames.py)")
    parser.add_argument("--markdown", type=Path, default=None,
                        help="also write the README's table rows for this run here (header included)")
    parser.add_argument("--fusion", choices=("auto", "off", "on", "both"), default="auto",
                        help="odometry from the twin's MCU fused in the infer stage: off (vision only), on, or both "
                             "(one after the other); auto: both for the fusion scenarios (drive, drive_clean, "
                             "blackout, drive_kidnap, mcu_loss), else off")


def variants(sc, fusion: str) -> list[str]:  # noqa: ANN001
    """The runs of one scenario: "vision_only" and/or "fused"."""
    if fusion == "auto":
        fusion = "both" if sc.fusion else "off"
    return {"off": ["vision_only"], "on": ["fused"], "both": ["vision_only", "fused"]}[fusion]


def run(args: argparse.Namespace) -> int:
    # A mistake raises, named (UsageError, a config or validation error; BenchError when a run cannot be
    # measured): courtloc.cli prints it as one line. What the command line asks is checked before any run.
    names = [n.strip() for n in args.scenario.split(",") if n.strip()]
    scenarios = build_scenarios(names, args)
    infer_fields = _parse_fields(args.infer)
    # The deployment of the first run, built and dropped: a bad --config or --infer field fails here, before
    # a stage starts (each run builds its own again with its port and store).
    deployment_for(scenarios[0], args, _free_port(), args.store or Path("store"), infer_fields)
    report: dict[str, Any] = {}
    for sc in scenarios:
        runs = {}
        for variant in variants(sc, args.fusion):
            runs[variant] = run_scenario(sc, args, infer_fields, fused=variant == "fused")
            _print_row(sc.name if len(runs) == 1 and variant == "vision_only" else f"{sc.name}/{variant}",
                       runs[variant])
        # One run: the scenario's keys as before (with "fusion" saying which); both: side by side.
        report[sc.name] = next(iter(runs.values())) if len(runs) == 1 else {"description": sc.description, **runs}
    report["run"] = {"court": args.court, "camera": args.camera, "seconds": args.seconds, "fps": args.fps,
                     "seed": args.seed, "tell_start": args.tell_start, "scenarios": names, "fusion": args.fusion,
                     "load_avg": list(os.getloadavg()), "cpus": os.cpu_count(),
                     "command": " ".join(["courtloc", *sys.argv[1:]])}
    text = json.dumps(report, indent=1)
    if args.markdown is not None:
        fused = any(r.get("fusion") == "fused" for _, r in scenario_rows(report))
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown_table(report) + "\n" + ("\n" + fusion_table(report) + "\n" if fused else ""))
    if args.json is not None and not json_to_stdout(args.json):
        args.json.parent.mkdir(parents=True, exist_ok=True)
    (args.json or json_output(JSON_STDOUT)).write_text(text + "\n")  # `--json -` or none: standard output
    return 0


def build_scenarios(names: list[str], args: argparse.Namespace) -> list:
    """The scenarios asked for, on a court and camera that exist: a mistake in any is one line naming it."""
    if not names:
        raise UsageError(f"--scenario {args.scenario!r}: no scenario given; known: {', '.join(SCENARIOS)}")
    unknown = [n for n in names if n not in SCENARIOS]
    if unknown:
        raise UsageError(f"--scenario: unknown scenario {', '.join(map(repr, unknown))}; "
                         f"known: {', '.join(SCENARIOS)}")
    try:
        load_court(args.court)
    except ValueError as exc:  # an unknown name, or a court JSON that is not one
        raise UsageError(f"--court {args.court}: {_first_error(exc)}") from exc
    if args.camera is not None:
        try:
            load_camera(args.camera)
        except ValueError as exc:
            raise UsageError(f"--camera {args.camera}: {_first_error(exc)}") from exc
    built = []
    for name in names:
        try:
            built.append(scenario(name, args.court, args.seconds, args.seed))
        except ValueError as exc:  # times scaled from --seconds that no longer make a scenario
            raise UsageError(f"--seconds {args.seconds:g} is too short for scenario {name!r}: "
                             f"{_first_error(exc)}") from exc
    return built


def _first_error(exc: ValueError) -> str:
    """A ValueError's reason in one line; for a pydantic ValidationError its first error, without its URL."""
    if isinstance(exc, ValidationError):
        error = exc.errors(include_url=False)[0]
        where = ".".join(str(p) for p in error.get("loc", ()))
        return f"{where + ': ' if where else ''}{str(error.get('msg', 'invalid')).removeprefix('Value error, ')}"
    return " ".join(str(exc).split())


def markdown_table(report: dict[str, Any]) -> str:
    """The README's table ("On the twin") for one run: one row per scenario."""
    def num(value: float | None, fmt: str, scale: float = 1.0) -> str:
        return "-" if value is None else fmt.format(value * scale)

    lines = ["| court | scenario | n | mean / median / p95 err (all) m | yaw median deg | valid | "
             "valid mean / p95 m | valid_wrong | recovery from a usable view mean / max s (from the event) |",
             "|---|---|---|---|---|---|---|---|---|"]
    court = report["run"]["court"]
    for name, r in scenario_rows(report):
        notes = "".join([f" ({num(r.get('recovery_from_event_s_mean'), '{:.2f}')} / "
                         f"{num(r.get('recovery_from_event_s_max'), '{:.2f}')})",
                         f" ({r['events_unrecovered']} unrecovered)" if r["events_unrecovered"] else "",
                         f", {r['events_without_view']} without a usable view" if r.get("events_without_view") else "",
                         f", {r['recovery_wrong']} first valid wrong" if r["recovery_wrong"] else ""])
        lines.append(
            f"| {court} | {name} | {r['n']} | {num(r['mean_err_m'], '{:.2f}')} / {num(r['median_err_m'], '{:.3f}')} / "
            f"{num(r['p95_err_m'], '{:.2f}')} | {num(r['yaw_median_deg'], '{:.2f}')} | "
            f"{num(r['valid_fraction'], '{:.1f}', 100)} % | {num(r['valid_mean_err_m'], '{:.2f}')} / "
            f"{num(r['valid_p95_err_m'], '{:.2f}')} | {r['valid_wrong']} | {num(r['recovery_s_mean'], '{:.2f}')} / "
            f"{num(r['recovery_s_max'], '{:.2f}')}{notes} |")
    return "\n".join(lines)


def scenario_rows(report: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(row name, result) per run: "blackout (vision only)", "blackout (fused)" for a scenario run both ways."""
    rows = []
    for name in report["run"]["scenarios"]:
        entry = report[name]
        if any(v in entry for v in VARIANTS):
            rows += [(f"{name} ({label})", entry[v]) for v, label in VARIANTS.items() if v in entry]
        else:
            rows.append((name if entry.get("fusion") != "fused" else f"{name} (fused)", entry))
    return rows


def fusion_table(report: dict[str, Any]) -> str:
    """The fusion keys of the runs that have them: blackout growth and validity, kidnap noticing."""
    def num(value: float | None, fmt: str, scale: float = 1.0) -> str:
        return "-" if value is None else fmt.format(value * scale)

    lines = ["| court | run | mean / p95 err (all) m | valid mean / p95 m | error_growth_m | valid in blackout | "
             "worst valid err in blackout m | kidnap noticed s | valid > 0.5 m after kidnap |",
             "|---|---|---|---|---|---|---|---|---|"]
    court = report["run"]["court"]
    for name, r in scenario_rows(report):
        b = r.get("blackout") or {}
        kidnaps = r.get("kidnaps") or []
        noticed = ", ".join(num(k["noticed_s"], "{:.2f}") for k in kidnaps) or "-"
        wrong = ", ".join(str(k["valid_wrong_after"]) for k in kidnaps) or "-"
        lines.append(
            f"| {court} | {name} | {num(r['mean_err_m'], '{:.3f}')} / {num(r['p95_err_m'], '{:.3f}')} | "
            f"{num(r['valid_mean_err_m'], '{:.3f}')} / {num(r['valid_p95_err_m'], '{:.3f}')} | "
            f"{num(b.get('error_growth_m'), '{:.3f}')} | {num(b.get('valid_fraction_blackout'), '{:.0f}', 100)}"
            f"{' %' if b.get('valid_fraction_blackout') is not None else ''} | "
            f"{num(b.get('max_valid_error_blackout_m'), '{:.3f}')} | {noticed} | {wrong} |")
    return "\n".join(lines)


def _parse_fields(items: list[str]) -> dict[str, Any]:
    fields: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--infer {item!r}: expected FIELD=VALUE")
        try:
            fields[key] = json.loads(value)
        except json.JSONDecodeError:
            fields[key] = value
    return fields


def _fmt(value: Any, scale: float = 1.0, digits: int = 3) -> str:
    return "-" if value is None else f"{value * scale:.{digits}f}"


def _print_row(name: str, r: dict[str, Any]) -> None:
    print(f"{name:14s} n {r['n']:5d}  err mean {_fmt(r['mean_err_m'])} med {_fmt(r['median_err_m'])} "
          f"p95 {_fmt(r['p95_err_m'])} m  valid {_fmt(r['valid_fraction'], 100, 1)}% "
          f"(valid mean {_fmt(r['valid_mean_err_m'])} p95 {_fmt(r['valid_p95_err_m'])} m)  "
          f"valid_wrong {r['valid_wrong']}  recovery mean {_fmt(r['recovery_s_mean'], digits=2)} "
          f"max {_fmt(r['recovery_s_max'], digits=2)} s from a usable view (from the event "
          f"{_fmt(r.get('recovery_from_event_s_mean'), digits=2)} / {_fmt(r.get('recovery_from_event_s_max'), digits=2)}; "
          f"{r['events_unrecovered']}/{r['events']} unrecovered)  "
          f"camera {_fmt(r.get('camera_fps'), digits=1)} fps",
          file=sys.stderr, flush=True)


# ---- one scenario -----------------------------------------------------------------------------------
def deployment_for(sc, args: argparse.Namespace, port: int, store: Path,  # noqa: ANN001, ANN201
                   infer_fields: dict[str, Any], mcu_link: Path | None = None):
    """The base deployment's stage settings with the bench's bus, court and scenario camera; with
    `mcu_link`, the twin's MCU on a pty linked there, the bridge's port and the infer stage's fusion."""

    base = load_deployment(args.config).model_dump(mode="json", exclude_unset=True)
    endpoint = f"tcp/127.0.0.1:{port}"
    camera = args.camera or base.get("camera_model")  # the bench's, else the file's, else the court's own
    mcu = None if mcu_link is None else TwinMcuConfig(link=str(mcu_link),
                                                      silent_s=[sc.mcu_silent_s] if sc.mcu_silent_s else [])
    sim = sc.sim.model_copy(update={"camera": camera, "mcu": mcu})
    if camera is not None:
        base["camera_model"] = camera
    base.update(
        court=sc.sim.court,
        zenoh={"mode": "client", "connect": [endpoint]},
        router={"listen": [endpoint]},
        launcher={**base.get("launcher", {}), "services": list(SERVICES), "run_router": True},
        camera={**base.get("camera", {}), "source": "sim", "fps": args.fps, "sim": sim.model_dump(mode="json")},
        infer={**base.get("infer", {}), "store": str(store), "start": start_config(sc, args.tell_start),
               **infer_fields},
    )
    # What the deployment derives from its court and camera is derived again from the bench's (the base
    # file's court was seed-gazebo's by default: its empty colour marks must not stand for robocon2025's).
    for key in ("court", "camera"):
        base["infer"].pop(key, None)
    base.get("preprocess", {}).pop("marks", None)
    shooter = base.get("shooter_bridge", {})
    if "target" in shooter:  # the shooter aims at the bench's court, not the file's
        shooter["target"].pop("court", None)
    # Vision only means no odometry at all, whatever the base file says; fused keeps its [infer.fusion].
    base["infer"]["fusion"] = {**base["infer"].get("fusion", {}), "enabled": mcu_link is not None}
    if mcu_link is not None:
        # The pty appears when the camera (started last) opens its source: retry the port every 0.1 s.
        base["shooter_bridge"] = {**shooter, "link": {**shooter.get("link", {}), "port": str(mcu_link),
                                                      "reconnect_initial_s": 0.05, "reconnect_max_s": 0.1}}
    return DeploymentConfig.model_validate(base)


def start_config(sc, tell: str) -> dict[str, Any] | None:  # noqa: ANN001
    """`[infer] start` for the scenario: the start pose as a team would configure it, its half, or nothing."""
    x, y, yaw = sc.start_pose
    if tell == "pose":
        return {"x": x, "y": y, "yaw_deg": math.degrees(yaw)}
    if tell == "half":
        return {"half": "+x" if x > 0 else "-x"}
    return None


@dataclass
class _Record:
    truths: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    hits: dict = field(default_factory=dict)  # capture stamp -> the frame's edge hits (usable views)
    marks: dict = field(default_factory=dict)  # capture stamp -> the frame's colour marks (a kidnap's view: the side)
    walls: dict = field(default_factory=dict)  # capture stamp -> the frame's wall-clock capture time
    odometry: list = field(default_factory=list)  # the bridge's odometry messages, as they came (fused runs)
    taken: dict = field(default_factory=dict)  # capture stamp -> the odometry seqs its pose says the stage took in
    size: tuple[int, int] = (0, 0)  # the frames' width and height
    last_seq: int = -1
    undecodable: int = 0


class TwinRecorder(BusWatcher):
    """The watcher (liveliness, health) plus every pose, truth and frame's edge hits, decoded on its own
    thread."""

    def __init__(self, config) -> None:  # noqa: ANN001
        super().__init__(config)
        self.record = _Record()
        self.subscribed = threading.Event()
        self._samples: queue.Queue = queue.Queue()
        self._progress = threading.Condition()
        self._decoder = threading.Thread(target=self._decode, name="twin-recorder", daemon=True)

    def extra_subscribers(self, zsession):  # noqa: ANN001, ANN201
        robot = self.config.robot_id
        subs = [zsession.declare_subscriber(TOPICS[path].key(robot), self._keep(path))
                for path in ("camera/ground_truth", "infer/pose", "preprocess/edges", "shooter_bridge/odometry")]
        self._decoder.start()
        self.subscribed.set()
        return subs

    def _keep(self, path: str):  # noqa: ANN202 - zenoh callback: hand the payload over, nothing else
        def on_sample(sample) -> None:  # noqa: ANN001
            self._samples.put((path, bytes(sample.payload)))
        return on_sample

    def _decode(self) -> None:
        # Until stopped, then whatever is still queued: the last frames count too.
        while not (self._stop.is_set() and self._samples.empty()):
            try:
                path, payload = self._samples.get(timeout=0.5)
            except queue.Empty:
                continue
            try:
                message = codec.decode(payload, TOPICS[path].message)
                if isinstance(message, Edges):
                    self.record.hits[message.header.capture_mono_ns] = edges_hits(message)
                    self.record.marks[message.header.capture_mono_ns] = edges_marks(message)
                    self.record.walls[message.header.capture_mono_ns] = message.header.capture_wall_ns
                    self.record.size = (message.width, message.height)
                    continue
            except (codec.DecodeError, ValueError):
                self.record.undecodable += 1
                continue
            header = message.header
            if isinstance(message, Odometry):
                self.record.odometry.append(message)
            elif isinstance(message, GroundTruth):
                sample = TruthSample(header.seq, header.capture_mono_ns, message.x, message.y, message.yaw)
                with self._progress:
                    self.record.truths.append(sample)
                    self.record.last_seq = max(self.record.last_seq, header.seq)
                    self._progress.notify_all()
            elif isinstance(message, Pose):
                stamp = next((s for s in reversed(header.stamps) if s.stage == "infer"), header.stamps[-1])
                self.record.taken[header.capture_mono_ns] = message.odometry_seqs
                self.record.poses.append(PoseSample(header.capture_mono_ns, stamp.mono_ns, message.x, message.y,
                                                    message.yaw, header.valid, message.reason))

    def wait_seq(self, seq: int, timeout: float) -> bool:
        with self._progress:
            return self._progress.wait_for(lambda: self.record.last_seq >= seq, timeout)

    def _on_liveliness(self, sample) -> None:  # noqa: ANN001
        super()._on_liveliness(sample)
        with self._progress:
            self._progress.notify_all()

    def wait_alive(self, names: tuple[str, ...], timeout: float) -> bool:
        def all_alive() -> bool:
            with self._lock:
                return set(names) <= self.state.alive
        with self._progress:
            return self._progress.wait_for(all_alive, timeout)

    def close(self) -> None:
        super().close()
        if self._decoder.is_alive():
            self._decoder.join(timeout=5.0)


def run_scenario(sc, args: argparse.Namespace, infer_fields: dict[str, Any],  # noqa: ANN001
                 fused: bool = False) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="courtloc-twin-") as tmp:
        folder = Path(tmp)
        log_dir = args.logs / (f"{sc.name}_fused" if fused else sc.name) if args.logs else folder / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        config = deployment_for(sc, args, _free_port(), args.store or folder / "store", infer_fields,
                                mcu_link=folder / "mcu" if fused else None)
        supervisor = Supervisor(config, write_effective_config(config, folder), log_dir)
        recorder = TwinRecorder(config)
        stop = threading.Event()
        children = {c.name: c for c in supervisor.children}
        frames = int(math.ceil(args.seconds * args.fps))
        kill_seq = None if sc.infer_kill_at_s is None else int(math.ceil(sc.infer_kill_at_s * args.fps))
        kill_ns: int | None = None
        try:
            for child in supervisor.children:
                if child.name == "camera":
                    continue
                child.start(log_dir)
                if not child.ready.wait(15.0):
                    raise BenchError(f"{child.name} not ready after 15 s (log: {child.log_path})")
            recorder.start(stop)
            _wait_for_stages(sc.name, recorder, [children[n] for n in STAGES_BEFORE_CAMERA], log_dir)
            children["camera"].start(log_dir)
            deadline = time.monotonic() + 60.0 + 6.0 * args.seconds
            while recorder.record.last_seq < frames - 1:
                if time.monotonic() > deadline:
                    log.warning("scenario %s: only %d of %d frames before the deadline", sc.name,
                                recorder.record.last_seq + 1, frames)
                    break
                target = frames - 1 if kill_ns is not None or kill_seq is None else kill_seq
                if recorder.wait_seq(target, 0.25) and kill_seq is not None and kill_ns is None \
                        and recorder.record.last_seq >= kill_seq:
                    kill_ns = time.monotonic_ns()
                    children["infer"].process.kill()  # SIGKILL: no clean shutdown, as in a crash
                    log.info("scenario %s: killed infer at frame %d", sc.name, recorder.record.last_seq)
                supervisor.check()
            end_ns = time.monotonic_ns()
        finally:
            supervisor.stop_all()
            stop.set()
            recorder.close()
        summary = recorder.summary(supervisor.restarts(), 0.0)
        with recorder._lock:  # noqa: SLF001 - the watcher's own lock guards its state
            health = {name: dict(h.detail) for name, h in recorder.state.health.items()}
    truths = [t for t in recorder.record.truths if t.capture_ns <= end_ns]
    poses = [p for p in recorder.record.poses if p.capture_ns <= end_ns]
    events = scenario_events(sc, truths, poses, args.fps, kill_ns, real_time=fused)
    court = load_court(sc.sim.court)
    camera = load_camera(config.camera.sim.get("camera") or court.default_camera).name
    if args.keep_frames is not None:
        write_kept(args.keep_frames / f"{sc.name}{'_fused' if fused else ''}.json",
                   kept_run(sc.name, court.name, camera, fused, config, recorder.record, truths, poses))
    judge = view_judge(court.name, camera)
    events = with_views(events, truths, recorder.record.hits, judge, end_ns, recorder.record.marks)
    result = twin_metrics(poses, truths, events, end_ns)
    first = min((t.capture_ns for t in truths), default=0)
    last = max((t.capture_ns for t in truths), default=0)
    for row in result["recoveries"]:
        row["t_s"] = round((row.pop("start_ns") - first) / 1e9, 3)
    for row in result["wrong_runs"]:
        row["t_s"] = [round((row.pop("start_ns") - first) / 1e9, 3), round((row.pop("end_ns") - first) / 1e9, 3)]
    # Sim time is frames / fps: a camera that cannot render at fps plays the robot in slow motion.
    camera_fps = (len(truths) - 1) / ((last - first) / 1e9) if last > first else None
    if sc.blackout_s is not None:
        start_ns, end_ns_blind = (_first_capture(truths, t_s, args.fps, fused) for t_s in sc.blackout_s)
        if start_ns is not None:
            result["blackout"] = blackout_metrics(poses, truths, start_ns, end_ns_blind or end_ns)
    if sc.mcu_silent_s is not None:
        # The same windows in both runs: fused, the middle one is the MCU's cable out; vision only, nothing changes.
        out_ns, back_ns = (_first_capture(truths, t_s, args.fps, fused) for t_s in sc.mcu_silent_s)
        if out_ns is not None:
            back_ns = back_ns or end_ns + 1
            result["mcu_loss"] = {name: window_metrics(poses, truths, lo, hi) for name, (lo, hi) in
                                  (("before", (first, out_ns)), ("during", (out_ns, back_ns)),
                                   ("after", (back_ns, end_ns + 1)))}
    kidnaps = [e.start_ns for e in events if e.kind == "kidnap"]
    if kidnaps:
        result["kidnaps"] = kidnap_metrics(poses, truths, kidnaps, end_ns)
    result["fusion"] = "fused" if fused else "vision_only"
    if fused:  # what reached the infer stage: its fusion's counters and the bridge's odometry intake
        intake = ("fusion.", "odom_", "mcu_odometry", "mcu_connects", "superseded")
        result["odometry"] = {stage: {k: v for k, v in health.get(stage, {}).items() if k.startswith(intake)}
                              for stage in ("shooter_bridge", "infer")}
    result.update(description=sc.description, frames=len(truths), camera_fps=camera_fps,
                  restarts=summary["restarts_by_process"],
                  stale_or_dropped={name: {"dropped": s["dropped"], "stale": s["stale"]}
                                    for name, s in summary["stages"].items()})
    return result


def kept_run(name: str, court: str, camera: str, fused: bool, config: DeploymentConfig, record: _Record,
             truths: list, poses: list) -> KeptRun:
    """What `--keep-frames` writes: each pose's frame, in the order the infer stage answered them."""
    truth_at = {t.capture_ns: [t.x, t.y, t.yaw] for t in truths}
    by_seq: dict[int, list[Odometry]] = {}
    for message in record.odometry:
        by_seq.setdefault(message.source_seq, []).append(message)
    frames, carried, unkept = [], [], 0
    for p in poses:
        carried += record.taken.get(p.capture_ns, [])
        if p.capture_ns not in record.hits:  # a frame the bench did not see: its odometry goes with the next one
            continue
        odometry = []
        for seq in carried:
            # A seq names a message within the MCU's epoch: the one taken is the latest captured before the answer.
            before = [m for m in by_seq.get(seq, []) if m.header.capture_mono_ns <= p.published_ns]
            if before:
                odometry.append(max(before, key=lambda m: m.header.capture_mono_ns))
        unkept += len(carried) - len(odometry)
        carried = []
        frames.append(KeptFrame(capture_ns=p.capture_ns, capture_wall_ns=record.walls[p.capture_ns],
                                hits=record.hits[p.capture_ns].ravel().tolist(),
                                marks=record.marks[p.capture_ns].ravel().tolist(), truth=truth_at.get(p.capture_ns),
                                pose=[p.x, p.y, p.yaw], valid=p.valid, reason=p.reason, odometry=odometry))
    return KeptRun(command=" ".join(["courtloc", *sys.argv[1:]]), scenario=name, court=court, camera=camera,
                   fused=fused, start=config.infer.start, fusion=config.infer.fusion if fused else None,
                   size=list(record.size), dropped=_unanswered(record, poses), odometry_unkept=unkept, frames=frames)


def _unanswered(record: _Record, poses: list) -> int:
    """Frames whose edges the bench saw before the last pose of the run but the infer stage never answered."""
    answered = {p.capture_ns for p in poses}
    last = max(answered, default=-1)
    return sum(1 for ns in record.hits if ns <= last and ns not in answered)


def _wait_for_stages(name: str, recorder, stages: list, log_dir: Path,  # noqa: ANN001
                     timeout_s: float = 90.0) -> None:
    """Until every stage is alive on the bus; a stage process that exits meanwhile fails the scenario at
    once with the last line of its log (a refused model, a bad setting)."""
    deadline = time.monotonic() + timeout_s
    if not recorder.subscribed.wait(timeout_s):
        raise BenchError(f"scenario {name}: the bench's bus client did not connect to the router in {timeout_s:.0f} s")
    names = tuple(child.name for child in stages)
    while not recorder.wait_alive(names, 1.0):  # woken by liveliness; each second, also look for a dead stage
        for child in stages:
            if not child.alive():
                raise BenchError(f"scenario {name}: {child.name} exited (code {child.process.returncode}): "
                                 f"{_last_line(child.log_path)}")
        if time.monotonic() > deadline:
            with recorder._lock:  # noqa: SLF001 - the watcher's own lock guards its state
                missing = set(names) - recorder.state.alive
            raise BenchError(f"scenario {name}: stage(s) {sorted(missing)} not alive after {timeout_s:.0f} s "
                             f"(logs: {log_dir}; keep them with --logs)")


def _last_line(path: Path | None) -> str:
    try:
        lines = [line for line in path.read_text(errors="replace").splitlines() if line.strip()] if path else []
    except OSError:
        lines = []
    return lines[-1].strip() if lines else "(no output)"


def scenario_events(sc, truths: list, poses: list, fps: float, kill_ns: int | None,  # noqa: ANN001
                    real_time: bool = False) -> list:
    """Where each recovery window starts: the first pose of the run, the first frame after each kidnap and
    after each outage, and the first pose of the restarted infer process."""

    events = []
    if poses:
        events.append(Event("start", min(p.capture_ns for p in poses)))
    for t_s in sc.sim.kidnaps_s:
        start = _first_capture(truths, t_s, fps, real_time)
        if start is not None:
            events.append(Event("kidnap", start))
    for _, end_s in sc.sim.outages_s:
        start = _first_capture(truths, end_s, fps, real_time)
        if start is not None:
            events.append(Event("outage", start))
    if kill_ns is not None:
        after = [p.capture_ns for p in poses if p.published_ns > kill_ns]
        if after:
            events.append(Event("infer_restart", min(after)))
    return events


def _first_capture(truths: list, t_s: float, fps: float, real_time: bool = False) -> int | None:  # noqa: ANN001
    """Capture stamp of the first frame at or after sim time `t_s`: frame seq / fps, or with the twin's MCU
    (a sim in real time, sim/source.py) the capture stamp since frame 0's."""
    if real_time:
        zero = next((t.capture_ns for t in truths if t.seq == 0), None)
        if zero is None:
            return None
        return min((t.capture_ns for t in truths if t.capture_ns >= zero + int(round(t_s * 1e9)) - 1000),
                   default=None)
    seq = int(math.ceil(t_s * fps - 1e-9))
    return min((t.capture_ns for t in truths if t.seq >= seq), default=None)


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])

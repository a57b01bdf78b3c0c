"""`courtloc bench twin`: the metric arithmetic on constructed poses, the scenario events, and one short
real run (router + four stage processes) checking the report's keys and its pose-truth matching."""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from courtloc.bench_twin import deployment_for, scenario_events, scenario_rows, variants
from courtloc.bench_twin_metrics import (
    Event,
    PoseSample,
    TruthSample,
    blackout_metrics,
    kidnap_metrics,
    twin_metrics,
    window_metrics,
)
from courtloc.sim.scenarios import SCENARIOS, scenario

MS = 1_000_000
REQUIRED = ("n", "mean_err_m", "median_err_m", "p95_err_m", "yaw_median_deg", "valid_fraction", "valid_wrong",
            "recovery_s_mean", "recovery_s_max", "recovery_from_event_s_mean", "events_without_view")


def _truths(n: int) -> list[TruthSample]:
    """Frame k at t = 100 ms * k, standing at (k, 0) facing 0."""
    return [TruthSample(seq=k, capture_ns=100 * MS * k, x=float(k), y=0.0, yaw=0.0) for k in range(n)]


def _pose(k: int, dx: float, valid: bool, dyaw: float | None = 0.0, latency_ms: int = 30) -> PoseSample:
    return PoseSample(capture_ns=100 * MS * k, published_ns=100 * MS * k + latency_ms * MS, x=float(k) + dx, y=0.0,
                      yaw=dyaw, valid=valid, reason="" if valid else "low_quality")


def test_errors_over_all_poses_and_over_valid_ones():
    truths = _truths(10)
    # Errors 0.0 .. 0.9 m; frames 0-5 valid (errors 0 .. 0.5), 6-9 invalid; frame 3 valid with yaw 0.2 rad off.
    poses = [_pose(k, 0.1 * k, valid=k <= 5, dyaw=0.2 if k == 3 else 0.0) for k in range(10)]
    poses[5] = _pose(5, 0.6, valid=True)  # a valid pose 0.6 m off: the one valid_wrong
    r = twin_metrics(poses, truths, [Event("start", 0)], end_ns=10**10)
    errors = [0.1 * k for k in range(10)]
    errors[5] = 0.6
    valid_errors = errors[:6]
    assert r["n"] == 10 and r["valid_n"] == 6 and r["valid_fraction"] == pytest.approx(0.6)
    assert r["mean_err_m"] == pytest.approx(sum(errors) / 10)
    assert r["median_err_m"] == pytest.approx(sorted(errors)[4] / 2 + sorted(errors)[5] / 2)
    assert r["valid_mean_err_m"] == pytest.approx(sum(valid_errors) / 6)
    assert r["valid_wrong"] == 1 and r["valid_wrong_max_err_m"] == pytest.approx(0.6)
    # p95 by linear interpolation between order statistics: 0.9 * 0.55 + 0.8 * 0.45 over all ten.
    assert r["p95_err_m"] == pytest.approx(sorted(errors)[8] + 0.55 * (sorted(errors)[9] - sorted(errors)[8]))
    assert r["yaw_median_deg"] == pytest.approx(0.0) and r["valid_yaw_median_deg"] == pytest.approx(0.0)
    assert r["invalid_reasons"] == {"low_quality": 4}


def test_poses_are_matched_by_capture_stamp_not_by_order():
    truths = _truths(5)
    # Delivered out of order, one pose of a frame whose truth never arrived.
    poses = [_pose(3, 0.0, True), _pose(1, 0.0, True),
             PoseSample(capture_ns=123, published_ns=200, x=50.0, y=0.0, yaw=0.0, valid=True)]
    r = twin_metrics(poses, truths, [], end_ns=10**10)
    assert r["n"] == 2 and r["mean_err_m"] == pytest.approx(0.0) and r["unmatched_poses"] == 1
    assert r["recovery_s_mean"] is None and r["events"] == 0


def test_yaw_error_wraps_around_pi():
    truths = [TruthSample(0, 0, 0.0, 0.0, math.pi - 0.01)]
    r = twin_metrics([PoseSample(0, 1, 0.0, 0.0, -math.pi + 0.01, True)], truths, [], end_ns=10)
    assert r["yaw_median_deg"] == pytest.approx(math.degrees(0.02))


def test_recovery_is_start_of_view_to_first_valid_right_publication_and_censored_when_never():
    truths = _truths(40)
    # The start recovers at frame 3; after the kidnap at 20 frame 25 is valid 2 m off, frame 27 valid and right.
    valid_frames = set(range(3, 10)) | {25, 27}
    poses = [_pose(k, 2.0 if k == 25 else 0.0, valid=k in valid_frames) for k in range(40)]
    events = [Event("start", 0), Event("kidnap", 20 * 100 * MS), Event("outage", 30 * 100 * MS)]
    r = twin_metrics(poses, truths, events, end_ns=40 * 100 * MS)
    start, kidnap, outage = r["recoveries"]
    assert start["recovery_s"] == pytest.approx(0.33) and start["first_valid_wrong"] is False
    # A wrong valid pose recovers nothing: timed to the right one, and counted as a wrong first answer.
    assert kidnap["recovery_s"] == pytest.approx(0.73) and kidnap["first_valid_wrong"] is True
    assert kidnap["first_valid_err_m"] == pytest.approx(2.0)
    # Never valid again: counted with the time it had until the end of the run, as unrecovered.
    assert outage["recovered"] is False and outage["recovery_s"] == pytest.approx(1.0)
    assert r["recovery_s_mean"] == pytest.approx((0.33 + 0.73 + 1.0) / 3)
    assert r["recovery_s_max"] == pytest.approx(1.0)
    assert r["events_unrecovered"] == 1 and r["recovery_wrong"] == 1


def test_an_event_ends_at_the_next_one():
    truths = _truths(20)
    poses = [_pose(k, 0.0, valid=k >= 15) for k in range(20)]
    r = twin_metrics(poses, truths, [Event("start", 0), Event("kidnap", 10 * 100 * MS)], end_ns=20 * 100 * MS)
    first, second = r["recoveries"]
    assert first["recovered"] is False and first["recovery_s"] == pytest.approx(1.0)
    assert second["recovered"] is True and second["recovery_s"] == pytest.approx(0.53)


def test_recovery_is_timed_from_the_first_usable_view_and_from_the_event_beside_it():
    truths = _truths(60)
    # Valid from frame 14 on after the kidnap at 10 (first usable view: frame 12); valid at 21, before the
    # outage's first usable view (frame 25: odometry carried it); never valid after the restart at 40,
    # whose views never were usable; the run starts at 0 and its view is usable at once.
    valid_frames = set(range(2, 10)) | set(range(14, 20)) | set(range(21, 40))
    poses = [_pose(k, 0.0, valid=k in valid_frames) for k in range(60)]
    events = [Event("start", 0, view_ns=0), Event("kidnap", 10 * 100 * MS, view_ns=12 * 100 * MS),
              Event("outage", 20 * 100 * MS, view_ns=25 * 100 * MS), Event("infer_restart", 40 * 100 * MS, view_ns=None)]
    r = twin_metrics(poses, truths, events, end_ns=60 * 100 * MS)
    start, kidnap, outage, restart = r["recoveries"]
    assert start["recovery_s"] == pytest.approx(0.23) and start["recovery_from_event_s"] == pytest.approx(0.23)
    assert kidnap["recovery_s"] == pytest.approx(0.23) and kidnap["recovery_from_event_s"] == pytest.approx(0.43)
    assert kidnap["view_after_s"] == pytest.approx(0.2)
    assert outage["recovery_s"] == 0.0 and outage["recovery_from_event_s"] == pytest.approx(0.13)
    assert restart["recovered"] is False and restart["recovery_s"] is None
    assert restart["recovery_from_event_s"] == pytest.approx(2.0)
    assert r["recovery_s_mean"] == pytest.approx((0.23 + 0.23 + 0.0) / 3) and r["recovery_s_max"] == pytest.approx(0.23)
    assert r["recovery_from_event_s_max"] == pytest.approx(2.0)
    assert r["events_without_view"] == 1 and r["events_unrecovered"] == 1


def test_scenario_events_start_at_the_first_usable_frame():
    sc = scenario("outage", "seed-gazebo", seconds=20.0)
    (o_start, o_end), = sc.sim.outages_s
    fps = 10.0
    truths = [TruthSample(k, 1000 + 7 * k, 0.0, 0.0, 0.0) for k in range(200)]
    poses = [PoseSample(1000 + 7 * k, 1000 + 7 * k + 3, 0.0, 0.0, 0.0, True) for k in range(5, 200)]
    kill_ns = 1000 + 7 * 150 + 3
    events = scenario_events(sc, truths, poses, fps, kill_ns)
    assert [e.kind for e in events] == ["start", "outage", "infer_restart"]
    assert events[0].start_ns == 1000 + 7 * 5  # the first pose: the chain's first frame
    assert events[1].start_ns == 1000 + 7 * math.ceil(o_end * fps)
    assert events[2].start_ns == 1000 + 7 * 151  # the first frame the restarted process answered
    kid = scenario("kidnap", "seed-gazebo", seconds=15.0)  # kidnaps at 5 and 10 s: frames 50, 100
    assert [e.kind for e in scenario_events(kid, truths, poses, fps, None)] == ["start", "kidnap", "kidnap"]


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_every_scenario_builds_for_both_courts(name: str):
    from courtloc.sim.source import SimSource

    for court in ("seed-gazebo", "robocon2025"):
        sc = scenario(name, court, seconds=12.0)
        with SimSource(sc.sim) as source:  # opening validates the start pose and the trajectory on this court
            assert source.pose_at_index(0) == pytest.approx(sc.start_pose)


def test_bench_twin_runs_the_chain_and_writes_every_key(tmp_path: Path):
    out = tmp_path / "twin.json"
    result = subprocess.run([sys.executable, "-m", "courtloc", "bench", "twin", "--court", "seed-gazebo",
                             "--scenario", "clean", "--seconds", "2", "--json", str(out),
                             "--markdown", str(tmp_path / "table.md")],
                            capture_output=True, text=True, timeout=240)
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads(out.read_text())
    clean = report["clean"]
    for key in REQUIRED:
        assert key in clean
    assert clean["frames"] >= 60  # 2 s at 30 fps, every truth recorded
    assert 0 < clean["n"] <= clean["frames"] and clean["unmatched_poses"] == 0
    assert math.isfinite(clean["mean_err_m"]) and clean["valid_n"] == round(clean["valid_fraction"] * clean["n"])
    assert clean["events"] == 1 and clean["recoveries"][0]["kind"] == "start"
    assert report["run"]["court"] == "seed-gazebo" and report["run"]["scenarios"] == ["clean"]
    header, rule, row = (tmp_path / "table.md").read_text().strip().splitlines()
    assert header.count("|") == rule.count("|") == row.count("|")
    assert row.startswith(f"| seed-gazebo | clean | {clean['n']} | {clean['mean_err_m']:.2f} / ")
    assert f"| {clean['valid_wrong']} |" in row


def test_a_table_row_says_how_many_events_had_no_usable_view():
    """seed-gazebo's kidnaps: no view tells the robot's side, so they have no recovery time, and the row says so."""
    from courtloc.bench_twin import markdown_table

    poses = [_pose(k, 0.0, valid=k < 10) for k in range(30)]
    events = [Event("start", 0, view_ns=0), Event("kidnap", 10 * 100 * MS, view_ns=None)]
    r = twin_metrics(poses, _truths(30), events, end_ns=30 * 100 * MS)
    row = markdown_table({"run": {"court": "seed-gazebo", "scenarios": ["kidnap"]},
                          "kidnap": {**r, "fusion": "vision_only"}}).splitlines()[-1]
    assert row.startswith("| seed-gazebo | kidnap | 30 |")
    assert row.endswith("(1 unrecovered), 1 without a usable view |")


def test_bench_twin_refuses_an_unknown_scenario_in_one_line():
    result = subprocess.run([sys.executable, "-m", "courtloc", "bench", "twin", "--scenario", "clean,rainy"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert result.stderr.strip().count("\n") == 0 and "unknown scenario 'rainy'" in result.stderr


def test_json_dash_prints_the_report_alone_on_stdout_and_json_file_writes_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]):
    """`--json -` as in every verb (courtloc.cli.EPILOG): the JSON on stdout, the rows on stderr; no file "-"."""
    import courtloc.bench_twin as bench_twin
    from courtloc.cli import exit_status

    truths = _truths(10)
    measured = {**twin_metrics([_pose(k, 0.01, True) for k in range(10)], truths, [], end_ns=10**10),
                "fusion": "vision_only", "camera_fps": 10.0}
    monkeypatch.setattr(bench_twin, "run_scenario", lambda sc, args, fields, fused=False: dict(measured))
    monkeypatch.chdir(tmp_path)
    assert exit_status(["bench", "twin", "--scenario", "clean", "--seconds", "1", "--json", "-"]) == 0
    out = capsys.readouterr().out
    assert json.loads(out)["clean"]["n"] == 10 and not (tmp_path / "-").exists()
    written = tmp_path / "new" / "twin.json"
    assert exit_status(["bench", "twin", "--scenario", "clean", "--seconds", "1", "--json", str(written)]) == 0
    assert capsys.readouterr().out == "" and json.loads(written.read_text())["run"]["scenarios"] == ["clean"]


def test_the_infer_stage_is_told_the_scenarios_start(tmp_path: Path):
    import argparse

    from courtloc.bench_twin import deployment_for
    from courtloc.services.deployment import sim_start

    sc = scenario("minus_x_start", "robocon2025", seconds=10.0)

    def config(tell: str):
        args = argparse.Namespace(config=None, camera=None, fps=30.0, tell_start=tell)
        return deployment_for(sc, args, 7999, tmp_path / "store", {})

    told = config("pose")
    assert told.infer.start is not None and (told.infer.start.x, told.infer.start.y) == (-3.0, 1.0)
    assert told.infer.start.yaw_deg == pytest.approx(math.degrees(-0.5))
    assert told.infer.court == "robocon2025" and told.camera.sim["court"] == "robocon2025"
    # Derived from the bench's court, not the base file's (seed-gazebo by default, which has no colour marks).
    assert [m.name for m in told.preprocess.marks] == ["red", "blue"]
    assert told.zenoh.connect == ["tcp/127.0.0.1:7999"] and told.router.listen == told.zenoh.connect
    assert told.infer.store == tmp_path / "store"
    half = config("half").infer.start
    assert half is not None and half.half == "-x" and half.x is None
    assert config("none").infer.start is None
    # `courtloc up` with a sim random walk that starts elsewhere than the centre: the start it derives.
    derived = sim_start(sc.sim)
    assert derived is not None and (derived.x, derived.y) == (-3.0, 1.0)


def test_valid_wrong_poses_are_grouped_into_runs():
    truths = _truths(12)
    # Frames 2-4 valid and 1 m off with yaw pi off (the twin), 5 invalid, 7 valid and 0.8 m off, rest right.
    poses = [_pose(k, 1.0 if k in (2, 3, 4, 5) else 0.8 if k == 7 else 0.0, valid=k != 5,
                   dyaw=math.pi if k in (2, 3, 4) else 0.0) for k in range(12)]
    runs = twin_metrics(poses, truths, [], end_ns=10**10)["wrong_runs"]
    assert [(r["start_ns"], r["end_ns"], r["poses"]) for r in runs] == [(200 * MS, 400 * MS, 3), (700 * MS, 700 * MS, 1)]
    assert runs[0]["max_err_m"] == pytest.approx(1.0) and runs[0]["yaw_err_median_deg"] == pytest.approx(180.0)
    assert runs[1]["max_err_m"] == pytest.approx(0.8) and runs[1]["yaw_err_median_deg"] == pytest.approx(0.0)


def test_a_stage_that_cannot_start_fails_the_bench_at_once_in_one_line(tmp_path: Path):
    not_a_dir = tmp_path / "file"
    not_a_dir.write_text("")
    bench = [sys.executable, "-m", "courtloc", "bench", "twin", "--scenario", "clean", "--seconds", "1"]
    with ThreadPoolExecutor(max_workers=2) as pool:  # two independent benches: side by side, not one after the other
        runs = [pool.submit(subprocess.run, [*bench, *extra], capture_output=True, text=True, timeout=120)
                for extra in (["--store", str(not_a_dir / "store")], ["--infer", "threads=0"])]
        result, bad = (run.result() for run in runs)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "infer exited" in lines[0] and "Not a directory" in lines[0]
    # A bad setting is a mistake in the command line (exit 2), refused before any stage starts.
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0 and "infer.threads" in bad.stderr


def test_blackout_growth_is_what_a_consumer_trusting_the_flag_holds():
    truths = _truths(40)  # the robot moves 1 m per frame (100 ms)
    start, end = 100 * MS * 20, 100 * MS * 30  # frames 20..29 are blind
    # Vision only: valid with 2 cm error before, invalid while blind (its x is a placeholder).
    vision = [_pose(k, 0.02, True) for k in range(20)] + [_pose(k, -float(k), False) for k in range(20, 30)]
    out = blackout_metrics(vision, truths, start, end)
    assert out["valid_fraction_blackout"] == 0.0 and out["max_valid_error_blackout_m"] is None
    # The newest valid pose is frame 19's (2 cm ahead): by frame 29 the robot is 9.98 m beyond it.
    assert out["held_error_max_m"] == pytest.approx(9.98) and out["error_growth_m"] == pytest.approx(9.96)
    assert out["error_before_m"] == pytest.approx(0.02) and out["blackout_frames"] == 10
    # Fused: valid throughout, the error growing to 7 cm at the end of the blackout.
    fused = [_pose(k, 0.02, True) for k in range(20)] + [_pose(k, 0.02 + 0.005 * (k - 19), True) for k in range(20, 30)]
    out = blackout_metrics(fused, truths, start, end)
    assert out["valid_fraction_blackout"] == 1.0
    assert out["error_growth_m"] == pytest.approx(0.05) and out["max_valid_error_blackout_m"] == pytest.approx(0.07)


def test_a_window_counts_its_poses_valid_and_valid_wrong():
    truths = _truths(30)
    poses = ([_pose(k, 0.01, True) for k in range(10)] + [_pose(k, 0.6, k % 2 == 0) for k in range(10, 20)]
             + [_pose(k, 0.0, False) for k in range(20, 30)])
    during = window_metrics(poses, truths, 100 * MS * 10, 100 * MS * 20)
    assert during == {"poses": 10, "valid_fraction": 0.5, "valid_wrong": 5, "max_valid_error_m": pytest.approx(0.6)}
    before = window_metrics(poses, truths, 0, 100 * MS * 10)
    assert before["valid_fraction"] == 1.0 and before["valid_wrong"] == 0
    after = window_metrics(poses, truths, 100 * MS * 20, 100 * MS * 30)
    assert after["valid_fraction"] == 0.0 and after["max_valid_error_m"] is None
    assert window_metrics(poses, truths, 100 * MS * 40, 100 * MS * 50)["valid_fraction"] is None


def test_the_mcu_loss_scenario_unplugs_the_twin_mcu_in_its_fused_run_only(tmp_path: Path):
    sc = scenario("mcu_loss", "robocon2025", 30.0)
    assert sc.mcu_silent_s == (10.0, 20.0) and variants(sc, "auto") == ["vision_only", "fused"]
    args = argparse.Namespace(camera=None, config=None, fps=30.0, tell_start="pose")
    fused = deployment_for(sc, args, 7447, tmp_path / "store", {}, mcu_link=tmp_path / "mcu")
    assert fused.camera.sim["mcu"]["silent_s"] == [[10.0, 20.0]] and fused.infer.fusion.enabled
    vision = deployment_for(sc, args, 7447, tmp_path / "store", {})
    assert vision.camera.sim["mcu"] is None and not vision.infer.fusion.enabled


def test_a_kidnap_is_noticed_at_the_first_invalid_pose_and_wrong_valid_ones_are_counted():
    truths = _truths(30)
    kidnap = 100 * MS * 10
    poses = ([_pose(k, 0.0, True) for k in range(10)] + [_pose(k, 2.0, True) for k in (10, 11)]
             + [_pose(k, 2.0, False) for k in range(12, 20)] + [_pose(k, 0.1, True) for k in range(20, 30)])
    (row,) = kidnap_metrics(poses, truths, [kidnap], 100 * MS * 30)
    assert row["valid_before"] is True
    assert row["noticed_s"] == pytest.approx(0.23)  # frame 12, 200 ms after the kidnap, published 30 ms later
    assert row["valid_before_noticed"] == 2 and row["valid_wrong_after"] == 2 and row["poses"] == 20
    never = kidnap_metrics([_pose(k, 2.0, True) for k in range(30)], truths, [kidnap], 100 * MS * 30)
    assert never[0]["noticed_s"] is None and never[0]["valid_wrong_after"] == 20


def test_fusion_scenarios_run_both_ways_by_default_and_report_side_by_side():
    assert variants(scenario("blackout", "seed-gazebo", 30.0), "auto") == ["vision_only", "fused"]
    assert variants(scenario("clean", "seed-gazebo", 30.0), "auto") == ["vision_only"]
    assert variants(scenario("kidnap", "seed-gazebo", 30.0), "both") == ["vision_only", "fused"]
    assert variants(scenario("blackout", "seed-gazebo", 30.0), "off") == ["vision_only"]
    blackout = scenario("blackout", "seed-gazebo", 30.0)
    assert blackout.blackout_s == (3.0, 5.0) and blackout.sim.outages_s == [(3.0, 5.0)]
    assert scenario("blackout", "seed-gazebo", 5.0).blackout_s == (2.0, 3.5)  # a short run: earlier, shorter
    report = {"run": {"scenarios": ["clean", "blackout", "kidnap"]}, "clean": {"fusion": "vision_only"},
              "blackout": {"description": "", "vision_only": {"a": 1}, "fused": {"a": 2}},
              "kidnap": {"fusion": "fused"}}
    assert [name for name, _ in scenario_rows(report)] == ["clean", "blackout (vision only)", "blackout (fused)",
                                                             "kidnap (fused)"]


def _children(pid: int) -> set[int]:
    """The live processes whose parent is `pid` (from /proc)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # ended meanwhile
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "(comm)": state, ppid, ...
        if int(fields[1]) == pid and fields[0] != "Z":
            found.add(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def test_a_killed_bench_stops_the_router_and_stages_it_started() -> None:
    """`kill` (SIGTERM) of a running `courtloc bench twin` ends it as Ctrl-C does: it stops the router and the
    four stage processes it started (before, they ran on with nobody to stop them) and exits 130."""
    import os
    import signal
    import time

    bench = subprocess.Popen([sys.executable, "-m", "courtloc", "bench", "twin", "--court", "seed-gazebo",
                              "--scenario", "clean", "--seconds", "60"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    started: set[int] = set()
    try:
        deadline = time.monotonic() + 120.0
        # The router and the four stages (the camera starts last, once the others are alive on the bus).
        while len(started := _children(bench.pid)) < 5:
            assert bench.poll() is None, bench.stderr.read()[-2000:]
            assert time.monotonic() < deadline, f"only {len(started)} child processes after 120 s"
            time.sleep(0.1)
        os.kill(bench.pid, signal.SIGTERM)
        assert bench.wait(timeout=60) == 130
        deadline = time.monotonic() + 30.0
        while any(_alive(pid) for pid in started) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [pid for pid in started if _alive(pid)]
    finally:
        if bench.poll() is None:
            bench.kill()
        for pid in started:  # orphans when the bench did not stop them
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)


def test_kept_frames_replayed_in_one_process_give_the_poses_the_infer_stage_published(tmp_path: Path):
    """`--keep-frames`: the frames the chain's infer stage answered, replayed through a fresh tracker in this process
    (openpilot's process replay), give the same poses, vision only and fused. A frame missing, out of order or with the
    wrong stamp, hits, marks or start, or (fused) an odometry message missing or offered a frame late, would set the
    replay's track elsewhere."""
    from courtloc.bench_twin_frames import read_kept, replay

    out, kept = tmp_path / "twin.json", tmp_path / "kept"
    result = subprocess.run([sys.executable, "-m", "courtloc", "bench", "twin", "--court", "robocon2025",
                             "--scenario", "randomised", "--seconds", "4", "--fusion", "both", "--json", str(out),
                             "--keep-frames", str(kept)], capture_output=True, text=True, timeout=360)
    assert result.returncode == 0, result.stderr[-3000:]
    reports = json.loads(out.read_text())["randomised"]
    for name, fused in (("randomised", False), ("randomised_fused", True)):
        report = reports["fused" if fused else "vision_only"]
        run = read_kept(kept / f"{name}.json")
        assert run.court == "robocon2025" and run.camera == "robocon2025" and run.start is not None
        assert run.fused == fused and (run.fusion is not None) == fused
        assert len(run.frames) == report["n"] and sum(f.valid for f in run.frames) == report["valid_n"] > 0
        assert any(f.marks for f in run.frames), "robocon2025's colour marks are kept with the hits"
        assert 0 <= run.dropped <= report["frames"] - len(run.frames)
        # 100 Hz odometry over 4 s, each message taken in before one answer (the bench saw them all).
        taken = sum(len(f.odometry) for f in run.frames)
        assert (taken > 100 and run.odometry_unkept == 0) if fused else taken == 0, (taken, run.odometry_unkept)
        replayed = replay(run)
        # The same code on the same machine: only a different BLAS thread count could reorder a sum (~1e-12 m).
        assert max(math.hypot(p.x - f.pose[0], p.y - f.pose[1]) for p, f in zip(replayed, run.frames)) < 1e-6, name
        # Validity as the localizer decided it; the stage itself refuses a stale or invalid input on top.
        judged = [(p.valid, f.valid) for p, f in zip(replayed, run.frames)
                  if f.reason not in ("stale_input", "invalid_input", "off_court")]
        assert len(judged) > 0.9 * len(run.frames) and all(a == b for a, b in judged), name

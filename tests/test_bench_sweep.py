"""`courtloc bench sweep`: twin walks under a chain's frame timings through the infer stage's tracker, in process."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_in_process import courtloc_in_process

from courtloc.bench_sweep import Walk, combine, frame_timing, parse_seeds, recoveries, summarise


def test_frame_timings_are_what_a_chain_delivers() -> None:
    n, fps = 3000, 30.0
    idx, t = frame_timing(n, fps, "all", np.random.default_rng(0))
    assert np.array_equal(idx, np.arange(n)) and np.allclose(t, idx / fps)
    idx, t = frame_timing(n, fps, "half", np.random.default_rng(0))
    assert np.array_equal(idx, np.arange(0, n, 2)) and np.allclose(t, idx / fps)
    idx, t = frame_timing(n, fps, "third", np.random.default_rng(0))
    assert np.array_equal(idx, np.arange(0, n, 3))
    for timing, lost in (("drop5", 0.05), ("drop25", 0.25)):
        idx, t = frame_timing(n, fps, timing, np.random.default_rng(0))
        # Binomial: the frames lost lie within 5 standard deviations of the rate.
        assert abs((n - len(idx)) - lost * n) <= 5 * np.sqrt(n * lost * (1 - lost))
        late = t - idx / fps  # capture jitter of a few milliseconds, never a frame period
        assert np.std(late) > 0.001 and np.max(np.abs(late)) < 0.5 / fps


def test_a_valid_pose_half_a_metre_off_is_counted_with_its_run() -> None:
    rows = [(0.0, False, 3.0), (0.1, True, 0.02), (0.2, True, 0.51), (0.3, True, 0.8), (0.4, True, 0.49)]
    one = {"seed": 4, "timing": "drop5", **summarise(rows)}
    other = {"seed": 5, "timing": "all", **summarise([(0.0, True, 0.01)])}
    report = combine([one, other])
    assert report["n"] == 6 and report["valid_wrong"] == 2
    assert report["valid_fraction"] == pytest.approx(5 / 6)
    assert report["valid_mean_err_m"] == pytest.approx((0.02 + 0.51 + 0.8 + 0.49 + 0.01) / 5)
    assert report["valid_wrong_runs"] == [{"seed": 4, "timing": "drop5", "valid_wrong": 2, "first_wrong_s": 0.2,
                                           "max_wrong_m": 0.8}]
    assert report["by_timing"] == {"drop5": {"n": 5, "valid_fraction": 0.8, "valid_wrong": 2},
                                   "all": {"n": 1, "valid_fraction": 1.0, "valid_wrong": 0}}


def test_kidnap_recoveries_are_timed_from_the_first_held_usable_view_to_a_right_pose() -> None:
    """10 fps, kidnaps at 1.0, 2.5 and 3.5 s. The first: a lone usable frame at 1.1 s, a held view from 1.5 s, valid
    again at 1.7 s. The second: valid and wrong from 2.7 s (before its first usable view, 2.9 s), right from 3.0 s.
    The third: usable from 3.6 s, never valid before the end."""
    n, fps = 40, 10.0
    walk = Walk(hits=[np.zeros((0, 4), np.int16)] * n, marks=[np.zeros((0, 3), np.int16)] * n,
                truth=np.zeros((n, 3)), width=640, height=480, odometry=[], kidnaps_s=[1.0, 2.5, 3.5])
    valid = {*range(0, 10), *range(17, 25), *range(27, 35)}
    rows = [(i / fps, i in valid, 3.0 if i in (27, 28, 29) else 0.02) for i in range(n)]
    usable = {*range(0, 10), 11, *range(15, 40)} - {25, 26, 27, 28, 35}
    events = recoveries(walk, fps, np.arange(n), rows, usable.__contains__)
    assert [e["event_s"] for e in events] == [1.0, 2.5, 3.5]
    assert [e["recovered"] for e in events] == [True, True, False]
    assert [e["wrong"] for e in events] == [False, True, False]
    assert [round(e["recovery_s"], 9) for e in events] == [0.2, 0.1, 0.3]
    report = combine([{"seed": 2, "timing": "all", **summarise(rows), "recoveries": events}])
    assert report["events"] == 3 and report["events_unrecovered"] == 1 and report["recovery_wrong"] == 1
    assert report["recovery_s_mean"] == pytest.approx(0.2) and report["recovery_s_max"] == pytest.approx(0.3)
    assert report["slowest_recovery"]["seed"] == 2 and report["slowest_recovery"]["event_s"] == 3.5
    # Frames that do not show the robot's side are no kidnap view: from 1.7 s, when it was already valid.
    sided = recoveries(walk, fps, np.arange(n), rows, usable.__contains__, lambda i: i not in (15, 16))
    assert round(sided[0]["recovery_s"], 9) == 0.0
    # No frame shows it: a kidnap never recovered has no view to time from (events_without_view).
    blind = recoveries(walk, fps, np.arange(n), rows, usable.__contains__, lambda i: False)
    assert blind[2]["recovery_s"] is None and combine([{"seed": 2, "timing": "all", **summarise(rows),
                                                        "recoveries": blind}])["events_without_view"] == 1
    # Frames the timing did not deliver are not views: every second frame, the first one is 1.6 s, back at 1.8 s.
    half = np.arange(0, n, 2)
    events = recoveries(walk, fps, half, [rows[i] for i in half], usable.__contains__)
    assert round(events[0]["recovery_s"], 9) == 0.2


def test_seeds_are_a_range_or_a_list() -> None:
    assert parse_seeds("3-6") == [3, 4, 5, 6]
    assert parse_seeds("1,7") == [1, 7]


def test_a_short_clean_walk_is_tracked_in_both_modes(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                     caplog: pytest.LogCaptureFixture) -> None:
    """Two seconds of the clean walk at every frame and every second frame: the frames the timings keep, vision
    only and fused, valid most of the time (the start pose is told) and never wrong."""
    out = tmp_path / "sweep.json"
    done = courtloc_in_process(["bench", "sweep", "--court", "seed-gazebo", "--scenario", "clean", "--seeds", "1",
                                "--seconds", "2", "--timings", "all,half", "--jobs", "1", "--json", str(out)],
                               capsys, caplog)
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    assert set(report["clean"]) == {"vision_only", "fused"}
    for mode in report["clean"].values():
        assert mode["runs"] == 2 and mode["n"] == 60 + 30
        assert mode["valid_fraction"] > 0.5 and mode["valid_wrong"] == 0
    assert report["run"]["seeds"] == [1] and "clean " in done.stdout


def test_a_scenario_the_sweep_cannot_model_is_refused_in_one_line(capsys: pytest.CaptureFixture[str],
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    done = courtloc_in_process(["bench", "sweep", "--court", "robocon2025", "--scenario", "clean,mcu_loss", "--seeds",
                                "1", "--seconds", "2", "--timings", "all"], capsys, caplog)
    assert done.returncode == 2 and "mcu_loss" in done.stderr and done.stderr.strip().count("\n") == 0
    assert "Traceback" not in done.stderr

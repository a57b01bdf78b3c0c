"""`courtloc eval` is honest: valid-only metrics beside the all-frames ones, the start side and pose reach
the localizer, `dataset synth` output is read as it is, a court mismatch is said, CLI errors are one line."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_in_process import courtloc_in_process

from courtloc.lab.datasets import Dataset, DatasetError, recording_of
from courtloc.lab.eval import StartHint, evaluate, open_model
from courtloc.lab.metrics import compute_metrics, valid_metrics
from courtloc.sim.render import RenderOptions
from courtloc.sim.synth import SynthConfig, synth

OLD_KEYS = {"n", "mse", "mae_x", "mae_y", "mean_err_m", "median_err_m", "p95_err_m", "yaw_median_deg"}
VALID_KEYS = {"valid_fraction", "valid_mean_err_m", "valid_p95_err_m", "valid_wrong"}


def courtloc(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "courtloc", *args], capture_output=True, text=True, timeout=180)


@pytest.fixture(scope="module")
def synth_sets(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("synth")
    # Clean edge images on the seed court: the bundled localizer's own court and camera.
    synth(SynthConfig(court="seed-gazebo", n=10, out=root / "seed", seed=5, kind="edges",
                      render=RenderOptions()))
    synth(SynthConfig(court="robocon2025", n=2, out=root / "r25", seed=1, kind="raw"))
    return {"seed": root / "seed", "r25": root / "r25"}


def test_valid_metrics_by_hand() -> None:
    err = np.array([0.01, 0.02, 0.9, 3.0, 0.04])
    valid = np.array([True, True, True, False, False])
    m = valid_metrics(err, valid)
    assert m["valid_fraction"] == pytest.approx(0.6)
    assert m["valid_mean_err_m"] == pytest.approx((0.01 + 0.02 + 0.9) / 3)
    # p95 of (0.01, 0.02, 0.9): rank 0.95 * 2 = 1.9 -> 0.02 + 0.9 * (0.9 - 0.02)
    assert m["valid_p95_err_m"] == pytest.approx(0.02 + 0.9 * 0.88)
    assert m["valid_wrong"] == 1  # 0.9 m valid; the 3 m one is invalid and does not count
    none = valid_metrics(err, np.zeros(5, bool))
    assert none == {"valid_fraction": 0.0, "valid_mean_err_m": None, "valid_p95_err_m": None, "valid_wrong": 0}


def test_metrics_keep_todays_keys_and_add_the_valid_ones() -> None:
    truth = np.zeros((3, 2))
    pred = np.array([[0.1, 0.0], [1.0, 0.0], [0.0, 0.2]])
    old = compute_metrics(pred, truth).as_dict()
    new = compute_metrics(pred, truth, valid=np.array([True, True, False])).as_dict()
    assert set(old) == OLD_KEYS - {"yaw_median_deg"}
    assert set(new) == set(old) | VALID_KEYS
    assert {k: new[k] for k in old} == old  # the all-frames numbers do not change
    assert new["valid_wrong"] == 1 and new["valid_fraction"] == pytest.approx(2 / 3)
    nothing = compute_metrics(pred, truth, valid=np.zeros(3, bool)).as_dict()
    assert nothing["valid_mean_err_m"] is None and nothing["valid_p95_err_m"] is None  # present, null


def test_synth_output_is_read_as_it_is(synth_sets: dict[str, Path]) -> None:
    raw = Dataset(synth_sets["r25"], kind=None)
    assert raw.kind == "raw" and raw.court == "robocon2025" and raw.sequential is False
    assert raw.recording_ids() == ["synth_s1"]
    edges = Dataset(synth_sets["seed"], kind=None)
    assert edges.kind == "dots" and edges.court == "seed-gazebo"
    with pytest.raises(DatasetError, match="leave out --kind"):
        Dataset(synth_sets["r25"], kind="dots")
    assert recording_of("img_synth_s12_0000003.jpg") == "synth_s12"


def test_start_side_reaches_the_localizer(synth_sets: dict[str, Path]) -> None:
    dataset = Dataset(synth_sets["seed"], kind=None)
    far = np.abs(dataset.xy[:, 0]) > 1.5
    assert far.sum() >= 4  # both halves are represented in the 10 uniform poses
    for side, sign in (("+x", 1.0), ("-x", -1.0)):
        result = evaluate(open_model(None, start=StartHint(side=side)), dataset)
        chosen = result.valid & far
        assert chosen.sum() >= 2
        # Independent frames, no track: every valid answer is the twin in the stated half.
        assert np.all(sign * result.pred_xy[chosen, 0] > 0)
        right_half = chosen & (sign * dataset.xy[:, 0] > 0)
        assert right_half.any()
        err = np.hypot(*(result.pred_xy[right_half] - dataset.xy[right_half]).T)
        assert np.all(err < 0.5)


def test_start_pose_is_the_first_frames_previous_pose(synth_sets: dict[str, Path]) -> None:
    dataset = Dataset(synth_sets["seed"], kind=None)
    k = int(np.argmax(-dataset.xy[:, 0]))  # the frame furthest into the -x half
    truth = (float(dataset.xy[k, 0]), float(dataset.xy[k, 1]), float(dataset.yaw[k]))
    result = evaluate(open_model(None, start=StartHint(pose=truth)), dataset, np.array([k]))
    assert result.valid[0] and np.hypot(*(result.pred_xy[0] - dataset.xy[k])) < 0.2
    with pytest.raises(ValueError, match="not in the start side"):
        StartHint(side="+x", pose=truth)


def test_eval_cli_on_synth_output_warns_of_the_court_and_writes_both_kinds_of_keys(
        synth_sets: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "m.json"
    result = courtloc("eval", "--data", str(synth_sets["r25"]), "--json", str(out), "--no-progress")
    assert result.returncode == 0, result.stderr
    metrics = json.loads(out.read_text())
    assert set(metrics) == OLD_KEYS | VALID_KEYS and metrics["n"] == 2
    warnings = [line for line in result.stderr.splitlines() if "warning" in line]
    assert len(warnings) == 1 and "'robocon2025'" in warnings[0] and "'seed-gazebo'" in warnings[0]
    same = courtloc("eval", "--data", str(synth_sets["seed"]), "--no-progress", "--start-side=-x")
    assert same.returncode == 0 and "warning" not in same.stderr
    told = courtloc("eval", "--data", str(synth_sets["seed"]), "--no-progress", "--data-court", "robocon2025")
    assert told.returncode == 0 and told.stderr.count("warning") == 1 and "'robocon2025'" in told.stderr


@pytest.mark.parametrize("args, reason", [
    (["--data", "{missing}"], "image folder not found"),
    (["--data", "{r25}", "--kind", "dots"], "leave out --kind"),
    (["--data", "{r25}", "--start-pose", "1,2"], "--start-pose must be X,Y,YAW"),
    (["--data", "{r25}", "--start-side", "left"], "--start-side must be +x or -x"),
    (["--data", "{r25}", "--start-side", "-x"], "--start-side=-x"),
    (["--data", "{r25}", "--model", "{missing}"], "no model at"),
    (["--data", "{r25}", "--recordings", "nope"], "unknown recording"),
])
def test_eval_cli_errors_are_one_line(synth_sets: dict[str, Path], tmp_path: Path, args: list[str], reason: str,
                                      capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    filled = [a.format(missing=tmp_path / "missing", r25=synth_sets["r25"]) for a in args]
    # in this process: the exit code and the printed lines are the proof (the whole run above is a real one)
    result = courtloc_in_process(["eval", *filled, "--no-progress"], capsys, caplog)
    assert result.returncode != 0 and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and reason in lines[0] and lines[0].startswith("courtloc eval:")

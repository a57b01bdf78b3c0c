"""The package README (lab/report.py): crosseval table, verdicts and the package's own evaluation report."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from courtloc.lab.eval import default_model_path
from courtloc.lab.report import markdown_report
from courtloc.lab.seed_eval import chosen_settings
from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.manifest import read_manifest

METRICS = {"n": 40, "mse": 0.001, "mae_x": 0.01, "mae_y": 0.01, "mean_err_m": 0.0226, "median_err_m": 0.0158,
           "p95_err_m": 0.0550, "yaw_median_deg": 0.295}


def _direction(tuned_on: str, tested_on: str, chosen: dict, p95: float) -> dict:
    run = {"all": {**METRICS, "p95_err_m": p95}, "valid_fraction": 0.98, "ms_median": {"track": 0.8}}
    return {"tuned_on": tuned_on, "tested_on": tested_on, "chosen": chosen, "tracking": run, "cold_start": run}


def test_readme_has_verdicts_and_the_packages_own_evaluation(tmp_path: Path) -> None:
    manifest = read_manifest(default_model_path() / "model.onnx")
    config = LocalizerConfig()
    other = {**chosen_settings(config), "pixel_sigma": 0.123}
    crosseval = {"recordings": ["A", "B"], "directions": [_direction("A", "B", other, 0.075),
                                                          _direction("B", "A", chosen_settings(config), 0.055)]}
    report_dir = tmp_path / "report"
    report_dir.mkdir()
    (report_dir / "eval_A.json").write_text(json.dumps(METRICS))
    (report_dir / "eval_B.json").write_text(json.dumps({**METRICS, "mean_err_m": 0.0199}))
    shutil.copy(Path(__file__), report_dir / "error_cdf.png")  # any file: the README only links it

    text = markdown_report(manifest, config, crosseval, tmp_path)
    assert "- A -> B (tracking, all frames): mean <= 3 cm met, p95 <= 7 cm NOT met" in text
    assert "- B -> A (tracking, all frames): mean <= 3 cm met, p95 <= 7 cm met" in text
    # The config equals what was tuned on B, so A is held out and B is the tuning recording.
    assert "tuned on B, so any other recording is held out" in text
    assert "| A | 40 | 2.26 | 1.58 | 5.50 | 0.295 | held out |" in text
    assert "| B | 40 | 1.99 | 1.58 | 5.50 | 0.295 | tuning recording |" in text
    assert "![error cdf](report/error_cdf.png)" in text


def test_readme_without_any_evaluation_says_so(tmp_path: Path) -> None:
    manifest = read_manifest(default_model_path() / "model.onnx")
    text = markdown_report(manifest, LocalizerConfig(), None, tmp_path)
    assert "No evaluation attached." in text and "Evaluation report" not in text

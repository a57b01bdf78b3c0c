"""The package README: what the package is, its cross-recording numbers (from a crosseval JSON) and, when the
package folder holds one, the evaluation report of the package itself (`report/`: `courtloc eval` JSON + plots)."""
from __future__ import annotations

import json
from pathlib import Path

from courtloc.lab.seed_eval import chosen_settings
from courtloc.localizer.config import LocalizerConfig
from courtloc.localizer.manifest import Manifest

REPORT_DIR = "report"


def _row(name: str, m: dict, extra: str = "") -> str:
    return (f"| {name} | {m['n']} | {m['mean_err_m'] * 100:.2f} | {m['median_err_m'] * 100:.2f} | "
            f"{m['p95_err_m'] * 100:.2f} | {m.get('yaw_median_deg', float('nan')):.3f} | {extra} |")


def markdown_report(manifest: Manifest, config: LocalizerConfig, report: dict | None,
                    folder: Path | None = None) -> str:
    lines = [
        f"# {manifest.name} v{manifest.version}: geometric court localizer",
        "",
        f"Court `{manifest.court}`, camera `{manifest.camera}`. Input: radial-scan hits, int16 [K, 4] "
        "(row, col, ray, d). `model.onnx` maps hits to robot-frame floor points (the calibrated camera as a "
        "per-pixel table); numpy then fits x, y, yaw to the court's distance field (robust Gauss-Newton, "
        "global search when not tracking). Design: docs/localizer.md.",
        "",
        f"Config: edge offset {config.edge_offset_px} px, hit noise {config.fit.pixel_sigma} px, tilt prior "
        f"{config.fit.tilt_sigma_deg} deg, model error {config.fit.range_sigma} m per m of range, symmetry "
        f"'{config.symmetry}' (half {config.half}); tracking motion filter: fit covariance x "
        f"{config.motion.measurement_scale}, acceleration noise {config.motion.accel_sigma_mps2} m/s^2, "
        f"velocity decay {config.motion.velocity_tau_s} s; thin-band bias "
        f"{_knots(config.fit.band_bias_widths, config.fit.band_bias_samples)}. "
        f"Weights sha256 `{manifest.weights_sha256[:16]}...`.",
        "",
        "Load: `courtloc.localizer.predictor.load_predictor(<this folder>)`. Its `track(hits, width, height, "
        "state, t)` runs the motion filter of the tracking numbers below (what the infer stage runs); "
        "`predict(previous=...)` tracks frame by frame without it.",
        "",
    ]
    evaluation = _evaluation_section(folder / REPORT_DIR, config, report) if folder is not None else []
    if not report:
        lines += evaluation or ["No evaluation attached."]
        return "\n".join(lines) + "\n"
    lines += [
        "## Cross-recording evaluation",
        "",
        f"Data `{report.get('data', '')}`, {report.get('n_frames', '?')} frames, recordings "
        f"{', '.join(report['recordings'])}. Truth = labels interpolated at image time + {report.get('lag_s', 0)} s "
        "(the seed's labels lag its images). Command:",
        "",
        "```",
        report.get("command", "courtloc localizer crosseval --data <seed-gazebo> --json crosseval.json"),
        *([report["build_command"]] if report.get("build_command") else []),
        "```",
        "",
        "Tuned on one recording (edge offset with its thin-band bias measured at the true poses, hit noise, "
        "model error per metre of range, then the motion "
        "filter's noise: small grids, each scored by tracking the whole tuning recording; lowest p95 wins; the "
        "tilt prior is fixed), tested on the other: *tracking* = every frame in time order with the motion "
        "filter (prediction from the past frames, fused with the frame's fit by covariance; global search when "
        "there is no track; a fused frame is valid when its fit is, or when the fit is trackable and the "
        "filter's posterior stds are within the validity limits); *cold start* = global search alone on every "
        "k-th frame, no previous pose, symmetry by the configured half.",
        "",
        "| run | n | mean cm | median cm | p95 cm | yaw median deg | notes |",
        "|---|---|---|---|---|---|---|",
    ]
    for d in report["directions"]:
        tr, cs = d["tracking"], d["cold_start"]
        tag = f"{d['tuned_on']} -> {d['tested_on']}"
        lines.append(_row(f"tracking {tag}", tr["all"],
                          f"valid {tr['valid_fraction']:.3f}; chosen {d['chosen']}; ms median {tr['ms_median']}"))
        if "valid_only" in tr:
            lines.append(_row(f"tracking {tag}, valid only", tr["valid_only"]))
        lines.append(_row(f"cold start {tag}", cs["all"], f"valid {cs['valid_fraction']:.3f}; ms median {cs['ms_median']}"))
    verdict = []
    for d in report["directions"]:
        m = d["tracking"]["all"]
        met = {"mean <= 3 cm": m["mean_err_m"] <= 0.03, "p95 <= 7 cm": m["p95_err_m"] <= 0.07,
               "yaw median <= 0.4 deg": m.get("yaw_median_deg", 99) <= 0.4}
        verdict.append(f"- {d['tuned_on']} -> {d['tested_on']} (tracking, all frames): "
                       + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in met.items()))
    lines += ["", "Targets, as computed from the table:", *verdict, "",
              "Times here are Python wall times on a shared, loaded machine; use `courtloc bench localize`.", "",
              *evaluation]
    return "\n".join(lines) + "\n"


def _evaluation_section(report_dir: Path, config: LocalizerConfig, report: dict | None) -> list[str]:
    """This package's own `courtloc eval` runs (report/eval_<recording>.json) and the plots beside them."""

    runs = sorted(report_dir.glob("eval_*.json"))
    if not runs:
        return []
    tuned_on = [d["tuned_on"] for d in (report or {}).get("directions", []) if d["chosen"] == chosen_settings(config)]
    lines = ["## Evaluation report of this package", "",
             "`courtloc eval` of this folder: tracking every frame in time order as the infer stage does (motion "
             "filter, frame times from the file names), labels as recorded (no lag correction). "
             + (f"Its settings are the ones crosseval tuned on {tuned_on[0]}, so any other recording is held out."
                if tuned_on else "Which recording its settings were tuned on is not in the crosseval report."),
             "", "```"]
    for path in runs:
        rec = path.stem.removeprefix("eval_")
        lines.append(f"courtloc eval --data <shared>/datasets/seed-gazebo --recordings {rec} --model <this folder> "
                     f"--json {REPORT_DIR}/{path.name} --plots {REPORT_DIR}")
    lines += ["```", "", "| recording | n | mean cm | median cm | p95 cm | yaw median deg | notes |",
              "|---|---|---|---|---|---|---|"]
    for path in runs:
        rec = path.stem.removeprefix("eval_")
        lines.append(_row(rec, json.loads(path.read_text()), "tuning recording" if rec in tuned_on else "held out"))
    lines.append("")
    for png in sorted(report_dir.glob("*.png")):
        lines += [f"![{png.stem.replace('_', ' ')}]({REPORT_DIR}/{png.name})", ""]
    if (report_dir / "predictions.csv").is_file():
        lines += [f"Per-frame truth and prediction: `{REPORT_DIR}/predictions.csv`.", ""]
    lines += [f"`{REPORT_DIR}/` is documentation: `courtloc model push` sends a package's top-level files only.", ""]
    return lines


def _knots(widths: list[float], samples: list[float]) -> str:
    """The thin-band bias curve in words: off, or width -> offset pairs (both in scan steps)."""
    if not widths:
        return "off"
    pairs = ", ".join(f"{w:g}: {v:+.2f}" for w, v in zip(widths, samples))
    return f"(band width -> hit offset, scan steps) {pairs}"

"""`courtloc localizer build|crosseval|residuals`: build a geometric-localizer package; evaluate it across
recordings; show where its residual model is off on labelled frames."""
from __future__ import annotations

import argparse
import json
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("localizer", help="geometric localizer: build a package, cross-recording evaluation")
    ops = parser.add_subparsers(dest="localizer_op", metavar="OP")

    build = ops.add_parser("build", help="write a package folder (model.onnx + court/camera/config JSON + README)")
    build.add_argument("--out", type=Path, required=True)
    build.add_argument("--court", default="seed-gazebo", help="packaged court name or court JSON path")
    build.add_argument("--camera", help="packaged camera name or camera JSON path (default: the court's own, its "
                       "default_camera)")
    build.add_argument("--config", type=Path, help="LocalizerConfig JSON (default: built-in defaults)")
    build.add_argument("--report", type=Path, help="crosseval JSON: its numbers go into the manifest and README")
    build.add_argument("--no-band-bias", action="store_true", help="clear the config's thin-band bias (it is the "
                       "renderer's or camera's: calibrated on other frames it does not apply)")
    build.add_argument("--name", default="courtloc-geometric")
    build.add_argument("--version", type=int, default=1)
    build.set_defaults(func=_build)

    cross = ops.add_parser("crosseval", help="tune on one recording, test on the other, both ways (seed format)")
    cross.add_argument("--data", type=Path, required=True, help="seed-format folder (images/ + pose_data.csv)")
    cross.add_argument("--csv", type=Path)
    cross.add_argument("--court", default="seed-gazebo")
    cross.add_argument("--camera", default="seed-gazebo")
    cross.add_argument("--config", type=Path, help="base LocalizerConfig JSON")
    cross.add_argument("--lag-s", type=float, default=0.0147, help="label lag behind the image (0: raw labels)")
    cross.add_argument("--step", type=int, default=1, help="use every step-th frame")
    cross.add_argument("--cold-step", type=int, default=20, help="cold-start pass on every k-th test frame")
    cross.add_argument("--json", type=Path, required=True)
    cross.add_argument("--config-out", type=Path,
                       help="write a direction's tuned config (LocalizerConfig JSON): see --config-tuned-on")
    cross.add_argument("--config-tuned-on", help="--config-out takes the settings tuned on this recording "
                       "(default: the first direction's)")
    cross.add_argument("--no-band-bias", action="store_true",
                       help="do not calibrate the thin-band bias (docs/localizer.md): the fit assumes none")
    cross.set_defaults(func=_crosseval)

    resid = ops.add_parser("residuals", help="median hit residual at the true poses, by paint kind and range")
    resid.add_argument("--data", type=Path, required=True, help="seed-format folder (images/ + pose_data.csv)")
    resid.add_argument("--csv", type=Path)
    resid.add_argument("--model", type=Path, help="localizer package folder (default: the bundled one)")
    resid.add_argument("--lag-s", type=float, default=0.0147, help="label lag behind the image (0: raw labels)")
    resid.add_argument("--step", type=int, default=3, help="use every step-th frame")
    resid.add_argument("--no-band-bias", action="store_true", help="the package's config with the thin-band bias off")
    resid.add_argument("--json", type=Path)
    resid.set_defaults(func=_residuals)


def _config(path: Path | None):
    from courtloc.localizer.config import LocalizerConfig

    return LocalizerConfig.model_validate_json(path.read_text()) if path else LocalizerConfig()


def _build(args: argparse.Namespace) -> int:
    from courtloc.localizer.manifest import TrainingData
    from courtloc.localizer.package import build_package
    from courtloc.localizer.report import markdown_report
    from courtloc.sim.camera import load_camera
    from courtloc.sim.court import load_court

    court, config = load_court(args.court), _config(args.config)
    camera = load_camera(args.camera or court.default_camera)
    if args.no_band_bias:
        config.fit.band_bias_widths, config.fit.band_bias_samples = [], []
    report = json.loads(args.report.read_text()) if args.report else None
    metrics, data = {}, None
    if report:
        for d in report["directions"]:
            metrics[f"tracking_{d['tested_on']}"] = {k: float(v) for k, v in d["tracking"]["all"].items()}
            metrics[f"cold_start_{d['tested_on']}"] = {k: float(v) for k, v in d["cold_start"]["all"].items()}
        data = TrainingData(fingerprint=report.get("fingerprint", ""), recordings=report["recordings"],
                            n_frames=int(report.get("n_frames", 0)),
                            description="no learned weights: edge offset, thin-band bias, hit noise, range "
                                        "error and the tracker's motion noise tuned per recording (see README); "
                                        "court and camera from the digital twin")
    manifest = build_package(args.out, court, camera, config, args.name, args.version, metrics, data)
    (args.out / "README.md").write_text(markdown_report(manifest, config, report, args.out))
    print(json.dumps({"out": str(args.out), "name": manifest.name, "weights_sha256": manifest.weights_sha256}))
    return 0


def _fingerprint(args: argparse.Namespace) -> str:
    """Dataset.fingerprint of the frames crosseval used (every step-th), for the package manifest."""
    from courtloc.localizer.datasets import load_dataset

    dataset = load_dataset(args.data, args.csv, kind="dots")
    return dataset.fingerprint(range(0, len(dataset), args.step))


def _crosseval(args: argparse.Namespace) -> int:
    from courtloc.localizer.seed_eval import apply_settings, cross_recording, load_seed_frames
    from courtloc.sim.camera import load_camera
    from courtloc.sim.court import load_court

    frames = load_seed_frames(args.data, args.csv, args.lag_s, args.step)
    base = _config(args.config)
    report = cross_recording(load_court(args.court), load_camera(args.camera), frames, base,
                             cold_step=args.cold_step, calibrate_band_bias=not args.no_band_bias)
    report.update({"data": args.data.name, "lag_s": args.lag_s, "step": args.step, "n_frames": len(frames.hits),
                   "court": args.court, "camera": args.camera, "fingerprint": _fingerprint(args)})
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1))
    if args.config_out:
        directions = [d for d in report["directions"] if args.config_tuned_on in (None, d["tuned_on"])]
        if not directions:
            raise SystemExit(f"--config-tuned-on {args.config_tuned_on}: not one of {report['recordings']}")
        cfg = apply_settings(base, directions[0]["chosen"])
        args.config_out.write_text(cfg.model_dump_json(indent=1))
    for d in report["directions"]:
        t, c = d["tracking"]["all"], d["cold_start"]["all"]
        print(f"tuned {d['tuned_on']} -> tested {d['tested_on']} {d['chosen']}: tracking n={t['n']} "
              f"mean={t['mean_err_m']:.4f} median={t['median_err_m']:.4f} p95={t['p95_err_m']:.4f} "
              f"yaw_med={t['yaw_median_deg']:.3f} deg valid={d['tracking']['valid_fraction']:.3f} "
              f"ms={d['tracking']['ms_median']} | cold n={c['n']} mean={c['mean_err_m']:.4f} p95={c['p95_err_m']:.4f}")
    return 0


def _residuals(args: argparse.Namespace) -> int:
    import numpy as np

    from courtloc.localizer.court_field import CourtField
    from courtloc.localizer.eval import default_model_path
    from courtloc.localizer.package import load_package
    from courtloc.localizer.residuals import residual_table
    from courtloc.localizer.seed_eval import load_seed_frames

    package = load_package(args.model or default_model_path())
    config = package.config
    if args.no_band_bias:
        config.fit.band_bias_widths, config.fit.band_bias_samples = [], []
    field = CourtField.from_court(package.court, config.field_resolution_m)
    frames = load_seed_frames(args.data, args.csv, args.lag_s, args.step)
    out = {}
    for rec in sorted(np.unique(frames.recordings).tolist()):
        rows = residual_table(package.camera, field, config, frames, np.nonzero(frames.recordings == rec)[0])
        out[rec] = rows
        print(f"recording {rec}: kind, range m, hits, median cm, mean cm")
        for r in rows:
            print(f"  {r['kind']:10s} {r['range_m'][0]:4.0f}-{r['range_m'][1]:<4.0f} {r['n']:7d} "
                  f"{r['median_cm']:+7.2f} {r['mean_cm']:+7.2f}")
    if args.json:
        args.json.write_text(json.dumps({"band_bias": not args.no_band_bias, "step": args.step,
                                         "recordings": out}, indent=1))
    return 0

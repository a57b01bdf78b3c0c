"""`courtloc shooter ...`: fit the physics prior to a measured table, and look up an RPM."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from courtloc.cli_errors import UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout, nonnegative_float
from courtloc.services.shooter_bridge.config import ShooterConfig, load_shooter_config, make_rpm_source
from courtloc.shot import ballistics
from courtloc.shot.rpm import RpmTable, TableError


def register(sub: argparse._SubParsersAction) -> None:
    shooter = sub.add_parser("shooter", help="shooter RPM: fit the physics prior to a table, look up an RPM")
    commands = shooter.add_subparsers(dest="shooter_command", metavar="SUBCOMMAND", required=True)

    fit = commands.add_parser("fit", help="fit the prior's slip (and drag) to a measured distance_m,rpm table")
    fit.add_argument("table", type=Path, help="CSV with header distance_m,rpm")
    fit.add_argument("--config", type=Path, help="shooter config (TOML); its physics and mount are the start point")
    fit.add_argument("--no-drag", action="store_true", help="keep the config's drag, fit slip only")
    add_json_argument(fit)
    fit.set_defaults(func=run_fit)

    rpm = commands.add_parser("rpm", help="the RPM for a distance (table if given, else the physics prior)")
    rpm.add_argument("distance", type=nonnegative_float,
                     help="floor distance from the release point to the ring centre, m (>= 0)")
    rpm.add_argument("--table", type=Path, help="CSV with header distance_m,rpm (overrides the config's)")
    rpm.add_argument("--config", type=Path, help="shooter config (TOML)")
    rpm.set_defaults(func=run_rpm)


def _load(config_path: Path | None) -> ShooterConfig:
    return load_shooter_config(config_path)  # a bad file or field raises ConfigError, named: one line


def _ring_height(config) -> float:  # noqa: ANN001
    return config.target.ring[2] if config.target.ring is not None else config.target.ring_centre()[2]


def run_fit(args: argparse.Namespace) -> int:
    config = _load(args.config)
    try:
        table = RpmTable.load(args.table)
    except TableError as exc:
        raise UsageError(str(exc)) from None
    base = config.rpm.physics.model(config.mount.release_height_m, _ring_height(config))
    try:
        result = ballistics.fit(table.distances_m, table.rpms, base, fit_drag=not args.no_drag)
    except ballistics.UnreachableShot as exc:
        raise UsageError(f"a table distance cannot be reached at this launch angle: {exc}") from None
    m = result.model
    if args.json is not None:
        args.json.write_text(json.dumps({
            "table": str(args.table), "rows": len(table.rpms), "slip": m.slip, "drag_per_m": m.drag_per_m,
            "launch_angle_deg": m.launch_angle_deg, "release_height_m": m.release_height_m,
            "wheel_radius_m": m.wheel_radius_m, "rms_rpm": result.rms_rpm, "max_abs_rpm": result.max_rpm,
            "residuals_rpm": list(result.residuals_rpm)}, indent=1))
        if json_to_stdout(args.json):
            return 0
    print(f"table {args.table}: {len(table.rpms)} rows, {table.range_m[0]:.2f}..{table.range_m[1]:.2f} m")
    print(f"fixed: launch {m.launch_angle_deg:g} deg, release {m.release_height_m:g} m, ring {m.ring_height_m:g} m, "
          f"wheel radius {m.wheel_radius_m:g} m")
    print(f"fitted: slip {m.slip:.4f}, drag {m.drag_per_m:.4f} /m{' (fixed)' if args.no_drag else ''}")
    print(f"residual: RMS {result.rms_rpm:.1f} rpm, max {result.max_rpm:.1f} rpm")
    print("distance_m,measured_rpm,prior_rpm,residual_rpm")
    for d, measured, residual in zip(table.distances_m, table.rpms, result.residuals_rpm):
        print(f"{d:.3f},{measured:.1f},{measured - residual:.1f},{residual:+.1f}")
    return 0


def run_rpm(args: argparse.Namespace) -> int:
    config = _load(args.config)
    if args.table is not None:
        config = config.model_copy(update={"rpm": config.rpm.model_copy(update={"table": args.table})})
    try:
        source = make_rpm_source(config, _ring_height(config))
    except TableError as exc:
        raise UsageError(str(exc)) from None
    lookup = source.lookup(args.distance)
    note = " (clamped: distance outside the table)" if lookup.clamped else ""
    print(f"{lookup.rpm:.0f}")
    print(f"from {source.describe()}{note}", file=sys.stderr)
    return 0

"""Shooter config (bad values name their field) and the `courtloc shooter` commands."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from courtloc.cli import main
from courtloc.common.config_loader import ConfigError
from courtloc.services.shooter_bridge.config import ShooterConfig, load_shooter_config

SHOOTER_DEPLOY = Path(__file__).resolve().parents[1] / "deploy" / "shooter"
EXAMPLE_TABLE = SHOOTER_DEPLOY / "example_rpm_table.csv"
EXAMPLE_CONFIG = SHOOTER_DEPLOY / "example_shooter.toml"


def test_example_config_loads_with_the_table_beside_it() -> None:
    config = load_shooter_config(EXAMPLE_CONFIG)
    assert config.rpm.table == EXAMPLE_TABLE.resolve()
    assert config.target.ring_centre() == pytest.approx((6.525, 0.0, 2.43))


@pytest.mark.parametrize("body, field", [
    ("[policy]\nmax_rpmm = 3\n", "policy.max_rpmm"),
    ("[policy]\nmin_rpm = 4000\nmax_rpm = 3000\n", "policy"),
    ("[link]\nbaud = -1\n", "link.baud"),
    ("[rpm.physics]\nlaunch_angle_deg = 95\n", "rpm.physics.launch_angle_deg"),
    ("[target]\nbasket = \"left\"\n", "target.basket"),
    ("[policy.area]\nkind = \"polygon\"\npolygon = [[0, 0], [1, 1]]\n", "policy.area"),
])
def test_bad_values_fail_with_the_field_name(tmp_path: Path, body: str, field: str) -> None:
    path = tmp_path / "shooter.toml"
    path.write_text(body)
    with pytest.raises(ConfigError, match=f"field {field}"):
        load_shooter_config(path)


def test_defaults_are_valid() -> None:
    assert ShooterConfig().policy.min_rpm <= ShooterConfig().policy.max_rpm


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as exit_info:
        main(list(argv))
    out, err = capsys.readouterr()
    return int(exit_info.value.code or 0), out, err


def test_cli_rpm_from_table_and_prior(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = _run(capsys, "shooter", "rpm", "4.0", "--table", str(EXAMPLE_TABLE))
    assert code == 0 and out.strip() == "2170"  # the table's own row
    code, out, err = _run(capsys, "shooter", "rpm", "20", "--table", str(EXAMPLE_TABLE))
    assert out.strip() == "2990" and "clamped" in err
    code, out, err = _run(capsys, "shooter", "rpm", "4.0")
    assert code == 0 and "physics prior" in err
    assert 1500 < float(out) < 2500  # defaults: 60 deg from 0.9 m, no drag, slip 0.7, 5 cm wheel: ~2081


def test_cli_fit_reports_slip_drag_and_residual(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = _run(capsys, "shooter", "fit", str(EXAMPLE_TABLE), "--config", str(EXAMPLE_CONFIG), "--json", "-")
    assert code == 0
    result = json.loads(out)
    assert result["slip"] == pytest.approx(0.7, abs=0.01)
    assert result["drag_per_m"] == pytest.approx(0.02, abs=0.003)
    assert result["rms_rpm"] < 5 and len(result["residuals_rpm"]) == result["rows"] == 12


def test_cli_fit_refuses_a_bad_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("distance_m,rpm\n3,abc\n")
    code, _, err = _run(capsys, "shooter", "fit", str(bad))
    assert code == 2 and "bad.csv:2" in err

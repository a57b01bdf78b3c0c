"""Calibration table: monotone PCHIP, clamping, parse errors and hot reload from a real file."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from courtloc.shot.rpm import RpmTable, TableError, TableWatcher

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "deploy" / "shooter" / "example_rpm_table.csv"

# Uneven spacing and a flat stretch: a cubic spline would overshoot here, PCHIP must not.
ROWS = "distance_m,rpm\n# comment\n2.0,1800\n2.5,1900\n3.0,2400\n5.0,2450\n5.5,2450\n8.0,3100\n"


def test_pchip_is_monotone_exact_at_rows_and_never_overshoots() -> None:
    table = RpmTable.parse(ROWS)
    for d, rpm in zip(table.distances_m, table.rpms):
        assert table.lookup(float(d)).rpm == pytest.approx(rpm)
    grid = np.linspace(2.0, 8.0, 2001)
    values = np.array([table.lookup(float(d)).rpm for d in grid])
    assert np.all(np.diff(values) >= -1e-9)
    flat = values[(grid >= 5.0) & (grid <= 5.5)]
    assert np.allclose(flat, 2450.0)  # no bump between equal rows
    for lo, hi, r_lo, r_hi in zip(table.distances_m, table.distances_m[1:], table.rpms, table.rpms[1:]):
        inside = values[(grid >= lo) & (grid <= hi)]
        assert inside.min() >= r_lo - 1e-9 and inside.max() <= r_hi + 1e-9


def test_clamped_at_both_ends() -> None:
    table = RpmTable.parse(ROWS)
    assert table.lookup(0.5).rpm == pytest.approx(1800) and table.lookup(0.5).clamped
    assert table.lookup(12.0).rpm == pytest.approx(3100) and table.lookup(12.0).clamped
    assert not table.lookup(4.0).clamped


@pytest.mark.parametrize("text, needle", [
    ("distance,rpm\n1,2\n2,3\n", "header"),
    ("distance_m,rpm\n1,2\n1,3\n", "twice"),
    ("distance_m,rpm\n1,2\n2,fast\n", ":3"),
    ("distance_m,rpm\n1,2\n", "at least 2"),
    ("distance_m,rpm\n1,2\n2,3,4\n", "2 columns"),
    ("distance_m,rpm\n1,2\n2,-3\n", "> 0"),
    ("# only a comment\n", "empty"),
])
def test_bad_tables_are_refused_with_where(text: str, needle: str) -> None:
    with pytest.raises(TableError, match=needle):
        RpmTable.parse(text, "t.csv")


def test_the_shipped_example_parses_and_rises() -> None:
    table = RpmTable.load(EXAMPLE)
    assert len(table.rpms) >= 8
    assert np.all(np.diff(table.rpms) > 0)


def _replace(path: Path, text: str) -> None:
    """Write as an editor or `cp` would do it safely: a new file renamed over the old one."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def test_hot_reload_the_next_lookup_uses_the_new_file(tmp_path: Path) -> None:
    path = tmp_path / "table.csv"
    path.write_text("distance_m,rpm\n2,2000\n6,3000\n")
    watcher = TableWatcher(path, min_interval_s=0.0)
    assert watcher.lookup(4.0).rpm == pytest.approx(2500)
    assert watcher.poll() is False  # nothing changed
    _replace(path, "distance_m,rpm\n2,2100\n6,3300\n")
    assert watcher.poll() is True
    assert watcher.lookup(4.0).rpm == pytest.approx(2700)
    assert watcher.reloads == 1


def test_in_place_edit_with_same_size_and_mtime_is_still_seen(tmp_path: Path) -> None:
    path = tmp_path / "table.csv"
    path.write_text("distance_m,rpm\n2,2000\n6,3000\n")
    watcher = TableWatcher(path, min_interval_s=0.0)
    before = os.stat(path)
    with open(path, "r+") as handle:  # same length, then the old timestamps put back
        handle.write("distance_m,rpm\n2,2000\n6,3400\n")
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    assert os.stat(path).st_size == before.st_size
    assert watcher.poll() is True
    assert watcher.lookup(6.0).rpm == pytest.approx(3400)


def test_bad_or_missing_file_keeps_the_last_good_table(tmp_path: Path) -> None:
    path = tmp_path / "table.csv"
    path.write_text("distance_m,rpm\n2,2000\n6,3000\n")
    watcher = TableWatcher(path, min_interval_s=0.0)
    _replace(path, "distance_m,rpm\n2,2000\n2,3000\n")
    assert watcher.poll() is False
    assert watcher.errors == 1 and "twice" in watcher.last_error
    assert watcher.lookup(6.0).rpm == pytest.approx(3000)
    path.unlink()
    assert watcher.poll() is False
    assert watcher.errors == 2
    assert watcher.lookup(6.0).rpm == pytest.approx(3000)
    _replace(path, "distance_m,rpm\n2,1000\n6,2000\n")
    assert watcher.poll() is True
    assert watcher.lookup(6.0).rpm == pytest.approx(2000)


def test_polls_are_throttled_by_the_clock(tmp_path: Path) -> None:
    now = [100.0]
    path = tmp_path / "table.csv"
    path.write_text("distance_m,rpm\n2,2000\n6,3000\n")
    watcher = TableWatcher(path, min_interval_s=1.0, clock=lambda: now[0])
    _replace(path, "distance_m,rpm\n2,2000\n6,3500\n")
    now[0] = 100.5
    assert watcher.poll() is False  # too soon: not even a stat
    assert watcher.lookup(6.0).rpm == pytest.approx(3000)
    now[0] = 101.0
    assert watcher.poll() is True
    assert watcher.lookup(6.0).rpm == pytest.approx(3500)


def test_missing_table_at_start_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(TableError, match="cannot read"):
        TableWatcher(tmp_path / "absent.csv")

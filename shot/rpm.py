"""Distance -> wheel RPM: a measured calibration table (hot-reloaded), or the physics prior.

Table file: CSV with the header `distance_m,rpm`, one measured pair per line; `#` starts a comment.
Between the rows the RPM follows a PCHIP curve (shape-preserving: a monotone table gives a monotone
curve with no overshoot); outside them it is clamped to the end rows and the lookup says so.
"""
from __future__ import annotations

import csv
import hashlib
import io
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Protocol, Sequence

import numpy as np

from courtloc.shot import ballistics

log = logging.getLogger(__name__)

HEADER = ("distance_m", "rpm")
# A file whose mtime is this close to the moment we read it may still change without its stat
# changing (coarse timestamps): keep comparing its content until it is older than this.
_RACY_WINDOW_NS = 2_000_000_000


class TableError(ValueError):
    """A calibration table that cannot be used; the message names the file and the line."""


@dataclass(frozen=True)
class RpmLookup:
    rpm: float
    clamped: bool  # the distance lay outside the table: the RPM is the nearest end row's


class RpmTable:
    def __init__(self, distances_m: Sequence[float], rpms: Sequence[float], source: str = "<table>") -> None:
        d = np.asarray(distances_m, dtype=float)
        r = np.asarray(rpms, dtype=float)
        if d.size < 2:
            raise TableError(f"{source}: needs at least 2 rows, has {d.size}")
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(r))):
            raise TableError(f"{source}: values must be finite numbers")
        if np.any(d < 0) or np.any(r <= 0):
            raise TableError(f"{source}: distances must be >= 0 and RPMs > 0")
        order = np.argsort(d, kind="stable")
        d, r = d[order], r[order]
        if np.any(np.diff(d) <= 0):
            raise TableError(f"{source}: distance {d[1:][np.diff(d) <= 0][0]} m appears twice")
        if np.any(np.diff(r) < 0):
            # Physically odd (farther should not need fewer RPM) but it is what was measured: keep it.
            log.warning("%s: RPM falls with distance somewhere; PCHIP keeps each piece monotone", source)
        self.distances_m = d
        self.rpms = r
        self.source = source
        from scipy.interpolate import PchipInterpolator  # see ballistics.solve(): imported where used

        self._curve = PchipInterpolator(d, r, extrapolate=False)

    @property
    def range_m(self) -> tuple[float, float]:
        return float(self.distances_m[0]), float(self.distances_m[-1])

    def lookup(self, distance_m: float) -> RpmLookup:
        low, high = self.range_m
        inside = low <= distance_m <= high
        at = min(max(distance_m, low), high)
        return RpmLookup(rpm=float(self._curve(at)), clamped=not inside)

    @classmethod
    def parse(cls, text: str, source: str = "<table>") -> "RpmTable":
        distances: list[float] = []
        rpms: list[float] = []
        header_seen = False
        for line_no, row in enumerate(csv.reader(io.StringIO(text)), start=1):
            cells = [c.strip() for c in row]
            if not cells or not cells[0] or cells[0].startswith("#"):
                continue
            if not header_seen:
                if tuple(c.lower() for c in cells[:2]) != HEADER or len(cells) != 2:
                    raise TableError(f"{source}:{line_no}: first row must be the header 'distance_m,rpm', got {row}")
                header_seen = True
                continue
            if len(cells) != 2:
                raise TableError(f"{source}:{line_no}: expected 2 columns (distance_m, rpm), got {len(cells)}")
            try:
                distance, rpm = float(cells[0]), float(cells[1])
            except ValueError:
                raise TableError(f"{source}:{line_no}: not numbers: {row}") from None
            distances.append(distance)
            rpms.append(rpm)
        if not header_seen:
            raise TableError(f"{source}: empty table (no 'distance_m,rpm' header)")
        return cls(distances, rpms, source)

    @classmethod
    def load(cls, path: Path) -> "RpmTable":
        try:
            text = Path(path).read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise TableError(f"{path}: cannot read: {exc}") from None
        return cls.parse(text, str(path))


class RpmSource(Protocol):
    def lookup(self, distance_m: float) -> RpmLookup: ...

    def poll(self, now_s: Optional[float] = None) -> bool: ...

    def describe(self) -> str: ...


class TableWatcher:
    """The calibration table, reloaded when its file changes.

    No thread: the owner calls `poll()` between frames (it does nothing until `min_interval_s` has
    passed). A change is seen through the file's stat (mtime, size, inode) or, while its mtime is
    recent, its content hash. A file that fails to parse, or vanishes, is logged and counted and the
    last good table keeps serving.
    """

    def __init__(self, path: Path, min_interval_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.path = Path(path)
        self.min_interval_s = min_interval_s
        self._clock = clock
        self.reloads = 0
        self.errors = 0
        self.last_error = ""
        self._signature: Optional[tuple[int, int, int]] = None
        self._digest = b""
        self._read_wall_ns = 0
        self._next_poll = -math.inf
        data = self._read()
        if data is None:
            raise TableError(f"{self.path}: cannot read: {self.last_error}")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise TableError(f"{self.path}: not UTF-8 text: {exc}") from None
        self.table = RpmTable.parse(text, str(self.path))
        self._next_poll = self._clock() + self.min_interval_s

    def _read(self) -> Optional[bytes]:
        try:
            st = os.stat(self.path)
            data = self.path.read_bytes()
        except OSError as exc:
            self.last_error = str(exc)
            return None
        self._signature = (st.st_mtime_ns, st.st_size, st.st_ino)
        self._read_wall_ns = time.time_ns()
        self._digest = hashlib.sha256(data).digest()
        return data

    def _changed_on_disk(self) -> bool:
        try:
            st = os.stat(self.path)
        except OSError as exc:
            if self.last_error != str(exc):
                log.warning("rpm table %s unavailable (%s); keeping the last good table", self.path, exc)
                self.errors += 1
                self.last_error = str(exc)
            return False
        if (st.st_mtime_ns, st.st_size, st.st_ino) != self._signature:
            return True
        return st.st_mtime_ns >= self._read_wall_ns - _RACY_WINDOW_NS

    def poll(self, now_s: Optional[float] = None) -> bool:
        """Reload the table if its file changed; True when a new table is now in use."""
        now = self._clock() if now_s is None else now_s
        if now < self._next_poll:
            return False
        self._next_poll = now + self.min_interval_s
        if not self._changed_on_disk():
            return False
        old_digest = self._digest
        data = self._read()
        if data is None or self._digest == old_digest:
            return False
        try:
            table = RpmTable.parse(data.decode("utf-8"), str(self.path))
        except (TableError, UnicodeDecodeError) as exc:
            self.errors += 1
            self.last_error = str(exc)
            log.error("rpm table not reloaded, the last good one keeps serving: %s", exc)
            return False
        self.table = table
        self.reloads += 1
        self.last_error = ""
        log.info("rpm table reloaded from %s: %d rows, %.2f..%.2f m", self.path, len(table.rpms), *table.range_m)
        return True

    def lookup(self, distance_m: float) -> RpmLookup:
        return self.table.lookup(distance_m)

    def describe(self) -> str:
        return f"table {self.path} ({len(self.table.rpms)} rows, {self.table.range_m[0]:.2f}..{self.table.range_m[1]:.2f} m)"


class PriorSource:
    """The physics prior, tabulated once on a distance grid so a lookup costs no integration."""

    def __init__(self, model: ballistics.ShotModel, min_distance_m: float = 0.5, max_distance_m: float = 10.0,
                 step_m: float = 0.1) -> None:
        grid = np.arange(min_distance_m, max_distance_m + step_m / 2, step_m)
        rows = ballistics.prior_table(model, grid)
        if len(rows) < 2:
            raise TableError(f"physics prior reaches the ring from fewer than 2 distances in "
                             f"{min_distance_m}..{max_distance_m} m: check launch angle and heights")
        self.model = model
        self.table = RpmTable([d for d, _ in rows], [r for _, r in rows], "physics prior")

    def poll(self, now_s: Optional[float] = None) -> bool:
        return False

    def lookup(self, distance_m: float) -> RpmLookup:
        return self.table.lookup(distance_m)

    def describe(self) -> str:
        m = self.model
        return (f"physics prior ({m.launch_angle_deg:g} deg, release {m.release_height_m:g} m, drag {m.drag_per_m:g}/m, "
                f"slip {m.slip:g}, wheel r {m.wheel_radius_m:g} m; {self.table.range_m[0]:.2f}..{self.table.range_m[1]:.2f} m)")

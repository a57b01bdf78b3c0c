"""The numbers of `courtloc bench twin`, from what was seen on the bus (pure: no bus, no processes).

Every pose is matched to the camera's ground truth of the same frame by the header's capture stamp
(the camera stamps the frame and its truth with one header, and every stage forwards that header).

- n, mean/median/p95_err_m, yaw_median_deg: over ALL matched poses, valid or not (what a consumer that
  ignores the flag would get); the same with the prefix `valid_` over the valid ones only.
- valid_fraction: valid poses / matched poses. valid_wrong: valid poses more than `wrong_m` off.
- recovery: for each event (the start of the run, a kidnap, the end of an outage, a restarted infer
  process) the first valid pose within `wrong_m` of the truth captured at or after its first frame (a valid
  pose that is wrong recovers nothing). `recovery_s`: from the capture of the first usable view since the
  event (`Event.view_ns`, courtloc/bench_twin_views.py: a view held over a few frames whose lines place the
  robot and, after a kidnap, that shows its side) to that pose's publication, 0 when the pose was valid and
  right before any usable view (odometry, a prior); `recovery_from_event_s`: from the event's first frame.
  An event not recovered before the next event (or the end of the run) counts with the time it had, as a
  lower bound, and is counted in `events_unrecovered`; one that also had no usable view has no
  `recovery_s` (`events_without_view`). Whether the event's first valid pose was wrong is kept per event
  and counted in `recovery_wrong`.
- wrong_runs: the valid-and-wrong poses grouped into runs of consecutive poses (in capture order), the
  first `MAX_RUNS`: where a run starts and ends, how many poses, the worst error and the median yaw error
  (a run ~180 degrees off is the point-symmetric twin).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from courtloc.lab.metrics import WRONG_M  # one "valid and wrong" threshold for eval and bench
from courtloc.world.angles import wrap_angle

MAX_RUNS = 20


@dataclass(frozen=True)
class TruthSample:
    seq: int
    capture_ns: int
    x: float
    y: float
    yaw: float


@dataclass(frozen=True)
class PoseSample:
    capture_ns: int
    published_ns: int
    x: float
    y: float
    yaw: float | None
    valid: bool
    reason: str = ""


FROM_EVENT = -1  # an event's views not judged: its first frame is taken as usable


@dataclass(frozen=True)
class Event:
    kind: str  # "start", "kidnap", "outage", "infer_restart"
    start_ns: int  # capture time of the first frame after it
    view_ns: int | None = FROM_EVENT  # capture time of the first usable view since; None: none before the next event

    def usable_from(self) -> int | None:
        return self.start_ns if self.view_ns == FROM_EVENT else self.view_ns


def _stats(err: np.ndarray, yaw_err: np.ndarray, prefix: str = "") -> dict[str, float | None]:
    if not err.size:
        return {f"{prefix}mean_err_m": None, f"{prefix}median_err_m": None, f"{prefix}p95_err_m": None,
                f"{prefix}yaw_median_deg": None}
    return {
        f"{prefix}mean_err_m": float(err.mean()),
        f"{prefix}median_err_m": float(np.median(err)),
        f"{prefix}p95_err_m": float(np.percentile(err, 95)),
        f"{prefix}yaw_median_deg": float(np.degrees(np.median(np.abs(yaw_err)))) if yaw_err.size else None,
    }


def in_windows(events: list[Event], end_ns: int) -> list[tuple[Event, int]]:
    """The events in capture order, each with the end of its window: the next event's first frame, or `end_ns`."""
    ordered = sorted(events, key=lambda e: e.start_ns)
    return [(e, ordered[i + 1].start_ns if i + 1 < len(ordered) else end_ns) for i, e in enumerate(ordered)]


def _recoveries(events: list[Event], matched: list[tuple[PoseSample, float]], end_ns: int,
                wrong_m: float) -> list[dict[str, Any]]:
    valid = sorted(((p, e) for p, e in matched if p.valid), key=lambda pe: pe[0].capture_ns)
    out = []
    for event, horizon in in_windows(events, end_ns):
        in_window = [(p, err) for p, err in valid if event.start_ns <= p.capture_ns < horizon]
        first = in_window[0] if in_window else None
        right = next(((p, err) for p, err in in_window if err <= wrong_m), None)
        view = event.usable_from()
        row: dict[str, Any] = {"kind": event.kind, "start_ns": event.start_ns,
                               "view_after_s": None if view is None else (view - event.start_ns) / 1e9,
                               "first_valid_err_m": None if first is None else first[1],
                               "first_valid_wrong": None if first is None else bool(first[1] > wrong_m)}
        if right is None:
            row.update(recovered=False, recovery_from_event_s=max(horizon - event.start_ns, 0) / 1e9,
                       recovery_s=None if view is None else max(horizon - view, 0) / 1e9)
        else:
            pose = right[0]
            # Valid and right before any usable view (odometry carried it, or a prior): nothing was waited for.
            waited = 0 if view is None or pose.capture_ns < view else max(pose.published_ns - view, 0)
            row.update(recovered=True, recovery_from_event_s=max(pose.published_ns - event.start_ns, 0) / 1e9,
                       recovery_s=waited / 1e9)
        out.append(row)
    return out


def _wrong_runs(matched: list[tuple[PoseSample, float, float | None]], wrong_m: float) -> list[dict[str, Any]]:
    runs: list[dict[str, Any]] = []
    current: list[tuple[PoseSample, float, float | None]] = []
    for item in sorted(matched, key=lambda m: m[0].capture_ns) + [None]:  # None closes the last run
        if item is not None and item[0].valid and item[1] > wrong_m:
            current.append(item)
            continue
        if current:
            yaws = [abs(y) for _, _, y in current if y is not None]
            runs.append({"start_ns": current[0][0].capture_ns, "end_ns": current[-1][0].capture_ns,
                         "poses": len(current), "max_err_m": max(e for _, e, _ in current),
                         "yaw_err_median_deg": float(np.degrees(np.median(yaws))) if yaws else None})
            current = []
    return runs[:MAX_RUNS]


def twin_metrics(poses: list[PoseSample], truths: list[TruthSample], events: list[Event], end_ns: int,
                 wrong_m: float = WRONG_M) -> dict[str, Any]:
    """The scenario's report (see the module docstring); `end_ns` ends the last recovery window."""
    by_stamp = {t.capture_ns: t for t in truths}
    matched: list[tuple[PoseSample, float]] = []
    yaw_errs: list[float | None] = []
    for pose in poses:
        truth = by_stamp.get(pose.capture_ns)
        if truth is None:
            continue
        matched.append((pose, math.hypot(pose.x - truth.x, pose.y - truth.y)))
        yaw_errs.append(None if pose.yaw is None else float(wrap_angle(pose.yaw - truth.yaw)))
    err = np.array([e for _, e in matched], dtype=np.float64)
    valid = np.array([p.valid for p, _ in matched], dtype=bool)
    has_yaw = np.array([y is not None for y in yaw_errs], dtype=bool)
    yaw = np.array([0.0 if y is None else y for y in yaw_errs], dtype=np.float64)
    recoveries = _recoveries(events, matched, end_ns, wrong_m)
    runs = _wrong_runs([(p, e, y) for (p, e), y in zip(matched, yaw_errs)], wrong_m)
    times = np.array([r["recovery_s"] for r in recoveries if r["recovery_s"] is not None], dtype=np.float64)
    from_event = np.array([r["recovery_from_event_s"] for r in recoveries], dtype=np.float64)
    reasons: dict[str, int] = {}
    for pose, _ in matched:
        if not pose.valid:
            reasons[pose.reason or "unknown"] = reasons.get(pose.reason or "unknown", 0) + 1
    return {
        "n": int(err.size),
        **_stats(err, yaw[has_yaw]),
        "valid_n": int(valid.sum()),
        "valid_fraction": float(valid.mean()) if err.size else None,
        **_stats(err[valid], yaw[valid & has_yaw], prefix="valid_"),
        "valid_wrong": int(np.count_nonzero(valid & (err > wrong_m))),
        "valid_wrong_max_err_m": float(err[valid & (err > wrong_m)].max()) if np.any(valid & (err > wrong_m)) else None,
        "wrong_m": wrong_m,
        "recovery_s_mean": float(times.mean()) if times.size else None,
        "recovery_s_max": float(times.max()) if times.size else None,
        "recovery_from_event_s_mean": float(from_event.mean()) if from_event.size else None,
        "recovery_from_event_s_max": float(from_event.max()) if from_event.size else None,
        "events": len(recoveries),
        "events_unrecovered": sum(not r["recovered"] for r in recoveries),
        "events_without_view": sum(r["recovery_s"] is None for r in recoveries),
        "recovery_wrong": sum(bool(r["first_valid_wrong"]) for r in recoveries),
        "recoveries": recoveries,
        "wrong_runs": runs,
        "invalid_reasons": reasons,
        "unmatched_poses": len(poses) - len(matched),
    }


def _matched_in_order(poses: list[PoseSample], truths: list[TruthSample]) -> list[tuple[PoseSample, float]]:
    by_stamp = {t.capture_ns: t for t in truths}
    pairs = [(p, by_stamp[p.capture_ns]) for p in poses if p.capture_ns in by_stamp]
    return sorted(((p, math.hypot(p.x - t.x, p.y - t.y)) for p, t in pairs), key=lambda pe: pe[0].capture_ns)


def blackout_metrics(poses: list[PoseSample], truths: list[TruthSample], start_ns: int, end_ns: int
                     ) -> dict[str, Any]:
    """Vision removed over captures [start_ns, end_ns): how far off is what a consumer that trusts the valid
    flag holds (the newest valid pose at each blind frame, against that frame's truth)?

    `error_growth_m`: the worst such error during the blackout minus the mean error of the poses in the
    second before it; `valid_fraction_blackout`; `max_valid_error_blackout_m` (the worst pose reported
    VALID during it: the number that must stay small); `blackout_frames` (truths in the window)."""
    matched = _matched_in_order(poses, truths)
    truth_at = {t.capture_ns: t for t in truths}
    before = [e for p, e in matched if start_ns - 1_000_000_000 <= p.capture_ns < start_ns and p.valid]
    held: PoseSample | None = None
    held_err: list[float] = []
    blind: list[tuple[PoseSample, float]] = []
    for pose, err in matched:
        if pose.capture_ns >= end_ns:
            break
        if pose.valid:
            held = pose
        if pose.capture_ns < start_ns:
            continue
        blind.append((pose, err))
        truth = truth_at[pose.capture_ns]
        held_err.append(math.inf if held is None else math.hypot(held.x - truth.x, held.y - truth.y))
    valid_err = [e for p, e in blind if p.valid]
    worst = max(held_err) if held_err else None
    return {
        "blackout_frames": sum(start_ns <= t.capture_ns < end_ns for t in truths),
        "blackout_poses": len(blind),
        "error_before_m": float(np.mean(before)) if before else None,
        "error_growth_m": None if worst is None or not before or not math.isfinite(worst)
        else float(worst - np.mean(before)),
        "held_error_max_m": None if worst is None or not math.isfinite(worst) else float(worst),
        "valid_fraction_blackout": float(np.mean([p.valid for p, _ in blind])) if blind else None,
        "max_valid_error_blackout_m": float(max(valid_err)) if valid_err else None,
    }


def window_metrics(poses: list[PoseSample], truths: list[TruthSample], start_ns: int, end_ns: int,
                   wrong_m: float = WRONG_M) -> dict[str, Any]:
    """The poses of captures [start_ns, end_ns): how many, how often valid, how many of those more than `wrong_m`
    off, and the worst valid one's error."""
    inside = [(p, e) for p, e in _matched_in_order(poses, truths) if start_ns <= p.capture_ns < end_ns]
    valid_err = [e for p, e in inside if p.valid]
    return {"poses": len(inside),
            "valid_fraction": len(valid_err) / len(inside) if inside else None,
            "valid_wrong": sum(e > wrong_m for e in valid_err),
            "max_valid_error_m": float(max(valid_err)) if valid_err else None}


def kidnap_metrics(poses: list[PoseSample], truths: list[TruthSample], kidnaps_ns: list[int], end_ns: int,
                   wrong_m: float = WRONG_M) -> list[dict[str, Any]]:
    """Per kidnap (capture of the first frame after it), until the next one or `end_ns`: `noticed_s` (to
    the publication of the first pose captured since that is marked invalid; None: never),
    `valid_wrong_after` (valid poses more than `wrong_m` off) and `valid_before_noticed` (valid poses
    published before it was noticed)."""
    matched = _matched_in_order(poses, truths)
    ordered = sorted(kidnaps_ns)
    rows = []
    for i, start in enumerate(ordered):
        horizon = ordered[i + 1] if i + 1 < len(ordered) else end_ns
        window = [(p, e) for p, e in matched if start <= p.capture_ns < horizon]
        first_invalid = next((p for p, _ in window if not p.valid), None)
        last_before = next((p for p, _ in reversed(matched) if p.capture_ns < start), None)
        rows.append({
            "valid_before": None if last_before is None else last_before.valid,  # False: nothing to notice
            "noticed_s": None if first_invalid is None else max(first_invalid.published_ns - start, 0) / 1e9,
            "valid_before_noticed": sum(p.valid for p, _ in window
                                        if first_invalid is None or p.capture_ns < first_invalid.capture_ns),
            "valid_wrong_after": sum(p.valid and e > wrong_m for p, e in window),
            "poses": len(window),
        })
    return rows

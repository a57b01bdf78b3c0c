"""`courtloc bench fuzz`: the hostile catalogue against a real chain (router + stage processes) on loopback.

The run is short and leaves out the slow-starting stages; the report's numbers are not asserted
(speed and memory are measured, never asserted), only what must hold whatever the machine: nothing
crashed, nothing hostile came out valid, and the refusals carry the reasons the catalogue provokes.
"""
from __future__ import annotations

import json
import random
import subprocess
from pathlib import Path

import msgpack
import pytest
from buskit import PYTHON

from courtloc.bench_fuzz import HOSTILE_SEQ, hostile_catalogue, mutate
from courtloc.common import codec
from courtloc.common.messages import Header, Pose
from courtloc.common.services_table import CONTROLS, TOPICS


def _refused(path: str, payload: bytes) -> bool:
    target = TOPICS.get(path) or CONTROLS[path]
    message = getattr(target, "message", None) or target.request
    try:
        decoded = codec.decode(payload, message, target.max_bytes)
    except codec.DecodeError:
        return True
    header = getattr(decoded, "header", None)
    return header is not None and not header.is_fresh(target.freshness_ms * 1e6)


def test_every_catalogue_entry_is_refused_by_the_contract_or_stale() -> None:
    """Those the contract cannot refuse alone (bombs, PNG, wrong frame size) are left to the stages."""
    seqs = iter(range(HOSTILE_SEQ, HOSTILE_SEQ + 1000))
    catalogue = hostile_catalogue("robot1", {}, lambda: next(seqs))
    names = {p.name for p in catalogue}
    assert {"decode_bomb", "png_as_jpeg", "stamps_1e6", "hits_1e6", "robot_id_5MB", "valid_yes",
            "chunk_50MB", "future_10s:infer/pose"} <= names
    left_to_stages = {"decode_bomb", "png_as_jpeg", "bad_file_name"}
    for probe in catalogue:
        if probe.name not in left_to_stages:
            assert _refused(probe.path, probe.payload), probe.name


def test_time_shifted_mutations_are_marked_must_not_be_valid() -> None:
    rng = random.Random(3)
    pose = Pose(header=Header.now("robot1", 1, "infer"), x=1.0, y=0.0, model_name="m", model_version=1,
                infer_ms=0.1).model_dump()
    checked = []
    for _ in range(200):
        payload, strict = mutate(pose, "robot1", rng, lambda c: HOSTILE_SEQ if c else 7)
        if strict:
            decoded = codec.decode(payload, Pose)
            assert decoded.header.seq == HOSTILE_SEQ and not decoded.header.is_fresh(150e6)
            checked.append(payload)
        else:
            assert isinstance(payload, bytes)
    assert checked and len({msgpack.unpackb(p)["header"]["capture_wall_ns"] for p in checked}) == len(checked)


@pytest.mark.integration
def test_fuzz_run_against_a_real_chain(tmp_path: Path) -> None:
    out = tmp_path / "fuzz.json"
    done = subprocess.run([*PYTHON, "bench", "fuzz", "--seconds", "3", "--json", str(out),
                           "--services", "preprocess", "shooter_bridge"], capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["crashes"] == 0 and report["restarts"] == {"router": 0, "preprocess": 0, "shooter_bridge": 0}
    assert report["hostile_set_rpm"] == 0 and report["sent_total"] > 0
    reasons = report["stages"]["preprocess"]["rejected_by_reason"]
    assert {"too_large", "invalid", "not_jpeg", "size"} <= set(reasons), reasons
    assert report["stages"]["shooter_bridge"]["stale"] > 0  # the future-stamped poses
    assert set(report["peak_rss_mb"]) == {"router", "preprocess", "shooter_bridge"}
    assert all(entry["tracebacks"] == 0 for entry in report["log"].values())

"""The transport baseline of `bench pipeline --relay` runs end to end: router + 4 hop processes in shared memory."""
from __future__ import annotations

import pytest

from courtloc.bench_pipeline import measure_relay

pytestmark = pytest.mark.integration


def test_relay_frames_reach_the_last_hop() -> None:
    relay = measure_relay(2.0, warmup_frames=5)
    assert relay["n"] > 0, "no frame crossed the 4 hops"
    assert relay["e2e_latency_ms_p50"] is not None and relay["e2e_latency_ms_p50"] > 0

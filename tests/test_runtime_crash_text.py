"""A stage worker's final crash text is bounded like every other string it reports (common/limits.py)."""
from __future__ import annotations

import logging

import pytest

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig
from courtloc.common.limits import MAX_TEXT_CHARS
from courtloc.common.messages import Health
from courtloc.common.runtime import Service


class _Crashing(Service):
    name = "camera"

    def produce(self) -> None:
        raise RuntimeError("x" * 100_000)  # e.g. a hostile input echoed into an exception's text


def test_a_worker_crash_is_reported_clipped_and_health_stays_valid(caplog: pytest.LogCaptureFixture) -> None:
    stage = _Crashing("robot1", ZenohConfig())
    with caplog.at_level(logging.CRITICAL):  # the traceback itself is the log's business, not this test's
        stage._work()
    assert stage.stop_event.is_set()  # run() stops the process
    assert stage.last_error.startswith("RuntimeError('xxx") and len(stage.last_error) == MAX_TEXT_CHARS
    health = stage.health()  # unclipped, this raised: no health message at all
    assert codec.decode(codec.encode(health), Health).last_error == stage.last_error

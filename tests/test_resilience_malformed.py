"""10,000 malformed payloads on every input topic of every stage that runs here: no crash, every one counted.

The runtime's inbox is bounded per topic: a payload that arrives while the worker is busy and the topic's
waiting payloads fill its depth pushes out the oldest, counted as `dropped`; a payload the worker takes and
cannot decode is counted as `rejected`. So for a burst of N bad payloads the stage's health must settle at
    rejected == frames_in  (everything taken was refused)   and   rejected + dropped == N.
The burst is published with BLOCK congestion control from one session so zenoh loses none in
transit; nothing waits per message.
"""
from __future__ import annotations

import random
from typing import Iterator

import msgpack
import pytest
import zenoh
from buskit import BusClient, Proc, free_port, start_router, start_stage, write_config

from courtloc.common.messages import SCHEMA_VERSION, Header, Health
from courtloc.common.services_table import SERVICES, TOPICS

pytestmark = pytest.mark.integration

BURST = 10_000


def _stages_under_test() -> list[str]:
    return [s for s in SERVICES if SERVICES[s].inputs]


def malformed_payloads(n: int, robot_id: str, seed: int = 0) -> Iterator[bytes]:
    """Bad payloads of every kind the codec must refuse: noise, truncation, wrong version, wrong types."""
    rng = random.Random(seed)
    header = Header.now(robot_id, 0, "test").model_dump()
    kinds = [
        lambda: rng.randbytes(rng.randint(0, 64)),
        lambda: msgpack.packb({"header": header, "pad": rng.randbytes(32)})[: rng.randint(1, 40)],
        lambda: msgpack.packb({"header": {**header, "schema_version": SCHEMA_VERSION + rng.randint(1, 9)}}),
        lambda: msgpack.packb({"header": {**header, "seq": "not a number"}}),
        lambda: msgpack.packb({"header": header}),  # right version, required fields missing
        lambda: msgpack.packb([1, 2, 3]),
        lambda: msgpack.packb({"header": None, "x": rng.random()}),
        lambda: msgpack.packb({"header": {**header, "robot_id": 42, "extra": [None] * 3}}),
        lambda: b"",
        lambda: b"\xc1" * rng.randint(1, 8),  # a byte msgpack never uses
    ]
    for i in range(n):
        yield kinds[i % len(kinds)]()


@pytest.fixture(scope="module")
def stages(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, dict[str, Proc]]]:
    names = _stages_under_test()
    if not names:
        pytest.skip("no consumer stage available")
    tmp = tmp_path_factory.mktemp("malformed")
    port = free_port()
    router = start_router(port)
    config = write_config(tmp / "stages.toml", port, f'[shooter_bridge.link]\nport = "{tmp / "no-mcu"}"\n'
                          if "shooter_bridge" in names else "", health_period_s=0.2)  # the tests wait on reports
    procs = {name: start_stage(name, config, verbose=False) for name in names}
    try:
        yield port, procs
    finally:
        for proc in procs.values():
            proc.stop()
        router.stop()


@pytest.mark.parametrize("path", sorted({p for s in SERVICES.values() for p in s.inputs}))
def test_burst_of_malformed_payloads_is_counted_and_survived(stages: tuple[int, dict[str, Proc]], path: str) -> None:
    port, procs = stages
    consumers = [name for name, spec in SERVICES.items() if path in spec.inputs and name in procs]
    if not consumers:
        pytest.skip(f"no running stage reads {path}")
    client = BusClient(port)
    for name in consumers:
        client.wait_alive(name)
        client.subscribe(f"{name}/health")
    publisher = client.session.declare_publisher(TOPICS[path].key(client.robot_id),
                                                 congestion_control=zenoh.CongestionControl.BLOCK)
    try:
        before = {name: client.wait_for(f"{name}/health") for name in consumers}
        for payload in malformed_payloads(BURST, client.robot_id):
            publisher.put(payload)
        for name in consumers:
            base = before[name]
            # A payload pushed out of the inbox unread is dropped, or superseded on a topic whose newest message
            # carries all the older ones did (odometry): either way counted.
            def accounted(h: Health, b: Health) -> int:
                return (h.rejected - b.rejected) + (h.dropped - b.dropped) + (_superseded(h) - _superseded(b))

            settled = client.wait_for(f"{name}/health", lambda h, b=base: accounted(h, b) >= BURST, timeout=60)
            rejected, dropped = settled.rejected - base.rejected, settled.dropped - base.dropped
            superseded = _superseded(settled) - _superseded(base)
            taken = settled.frames_in - base.frames_in
            assert rejected + dropped + superseded == BURST, \
                f"{name}: {rejected} rejected + {dropped} dropped + {superseded} superseded != {BURST}"
            assert (superseded == 0) if not TOPICS[path].newest_supersedes else (dropped == 0), (dropped, superseded)
            assert rejected == taken and rejected > 0, f"{name}: took {taken}, rejected {rejected}"
            assert settled.detail.get(f"rejected.{path}", 0) >= rejected
            assert procs[name].alive(), procs[name].output()
    finally:
        publisher.undeclare()
        client.close()


def _superseded(health: Health) -> int:
    value = health.detail.get("superseded", 0)
    assert isinstance(value, int)
    return value

"""zenoh itself bounds the largest message a session accepts off a link, from the services table.

Without the bound zenoh reassembled a fragmented payload of any size (1 GiB by default) in the receiver's
memory before our own size check refused it. With it, a bigger message is dropped on receipt, at the router
and at each stage, and the link stays up. Real router and stage processes; every wait is on an event.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pytest
import zenoh
from buskit import BusClient, Proc, endpoint, free_port, start_router, start_stage, write_config

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, build_zenoh_config
from courtloc.common.limits import ZENOH_FRAMING_MARGIN_BYTES
from courtloc.common.messages import Frame, Header
from courtloc.common.services_table import CONTROLS, MAX_BUS_MESSAGE_BYTES, RELAY_TOPICS, TOPICS

MAX_MESSAGE_KEY = "transport/link/rx/max_message_size"


def test_the_bound_is_the_tables_largest_payload_plus_zenohs_framing() -> None:
    largest = max([t.max_bytes for t in (*TOPICS.values(), *RELAY_TOPICS)] + [c.max_bytes for c in CONTROLS.values()])
    assert MAX_BUS_MESSAGE_BYTES == largest + ZENOH_FRAMING_MARGIN_BYTES
    assert MAX_BUS_MESSAGE_BYTES < 2**30 // 64  # far below zenoh's default of 1 GiB


@pytest.mark.parametrize("mode", ["client", "peer", "router"])
def test_every_session_we_open_carries_the_bound(mode: str, tmp_path: Path) -> None:
    own_file = tmp_path / "zenoh.json5"  # a team's zenoh file cannot lift it by accident
    own_file.write_text(json.dumps({"transport": {"link": {"rx": {"max_message_size": 2**30}}}}))
    for config_file in (None, own_file):
        zcfg = build_zenoh_config(ZenohConfig(mode=mode, config_file=config_file))
        assert json.loads(zcfg.get_json(MAX_MESSAGE_KEY)) == MAX_BUS_MESSAGE_BYTES


def _frame() -> bytes:
    ok, jpeg = cv2.imencode(".jpg", np.zeros((480, 640, 3), np.uint8))
    assert ok
    return codec.encode(Frame(header=Header.now("robot1", 1, "test"), width=640, height=480, encoding="jpeg",
                              data=jpeg.tobytes()))


class _PlainRouter:
    """A router with zenoh's defaults (1 GiB messages) and no shared memory, in this process: what reaches
    the stage is then bounded by the stage's own session only."""

    def __init__(self, port: int) -> None:
        zcfg = zenoh.Config()
        for path, value in (("mode", "router"), ("listen/endpoints", [endpoint(port)]),
                            ("scouting/multicast/enabled", False), ("transport/shared_memory/enabled", False)):
            zcfg.insert_json5(path, json.dumps(value))
        self.session = zenoh.open(zcfg)

    def stop(self) -> None:
        self.session.close()


@pytest.fixture(params=["our_router", "plain_router"])
def router(request: pytest.FixtureRequest) -> Iterator[tuple[int, Proc | _PlainRouter]]:
    port = free_port()
    started: Proc | _PlainRouter = start_router(port) if request.param == "our_router" else _PlainRouter(port)
    try:
        yield port, started
    finally:
        started.stop()


@pytest.mark.integration
def test_a_message_over_the_bound_never_reaches_the_stage_and_it_keeps_serving(
        tmp_path: Path, router: tuple[int, Proc | _PlainRouter]) -> None:
    port, _ = router
    client = BusClient(port)
    client.subscribe("preprocess/health")
    client.subscribe("preprocess/edges")
    # A sender without shared memory: its payloads cross every link as bytes, as from another host.
    sender = zenoh.open(build_zenoh_config(ZenohConfig(connect=[endpoint(port)], shared_memory=False)))
    stage = start_stage("preprocess", write_config(tmp_path / "deploy.toml", port, health_period_s=0.2))
    key = TOPICS["camera/frame"].key("robot1")

    def put(payload: bytes) -> None:  # BLOCK: a multi-megabyte payload must not be dropped by congestion
        sender.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    try:
        client.wait_alive("preprocess")
        client.wait_subscribed("camera/frame")
        before = client.wait_for("preprocess/health")
        too_large = before.detail.get("reject.too_large", 0)
        put(b"\0" * (MAX_BUS_MESSAGE_BYTES + 2**20))  # over the bound: zenoh drops it on receipt
        # Then, on the same key from the same sender (delivered in order), one under the bound but over the
        # topic's limit: it reaches the stage and is refused by our own size check. Once that one is counted,
        # the big one would have been taken or overwritten already had it arrived.
        put(b"\0" * (TOPICS["camera/frame"].max_bytes + 1))
        after = client.wait_for("preprocess/health", lambda h: h.detail.get("reject.too_large", 0) > too_large)
        assert after.detail["reject.too_large"] == too_large + 1
        assert after.frames_in == before.frames_in + 1 and after.dropped == before.dropped
        client.drain("preprocess/edges")
        put(_frame())
        edges = client.wait_for("preprocess/edges")
        assert edges.width == 640 and stage.alive()
    finally:
        sender.close()
        client.close()
        stage.stop()
    assert "Traceback" not in stage.output()

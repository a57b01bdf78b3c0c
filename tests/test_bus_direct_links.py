"""Stages on the router's host link up directly (zenoh peers on loopback); tools and other hosts go through
the router as before."""
from __future__ import annotations

import threading
from pathlib import Path

import pytest
import zenoh
from buskit import endpoint, free_port, start_router

from courtloc.common.bus import ZenohConfig, open_session
from courtloc.common.security import SecurityConfig

KEY = "courtloc/robot1/test/direct"


def test_a_stage_of_a_router_on_this_host_is_a_loopback_peer() -> None:
    links = ZenohConfig(connect=["tcp/127.0.0.1:7447"]).stage_links()
    assert (links.mode, links.listen) == ("peer", ["tcp/127.0.0.1:0"])
    assert ZenohConfig(connect=["tcp/localhost:7447"]).stage_links().mode == "peer"


@pytest.mark.parametrize("config", [
    ZenohConfig(connect=["tcp/192.168.1.20:7447"]),  # the robot's router from the pit laptop
    ZenohConfig(connect=["tcp/127.0.0.1:7447", "tcp/10.0.0.2:7447"]),
    ZenohConfig(connect=["tcp/127.0.0.1:7447"], direct_links=False),
    ZenohConfig(mode="router", listen=["tcp/127.0.0.1:7447"]),
])
def test_other_sessions_keep_their_config(config: ZenohConfig) -> None:
    assert config.stage_links() == config


def test_a_secured_deployment_opens_no_peer_listener(tmp_path: Path) -> None:
    config = ZenohConfig(connect=["tls/127.0.0.1:7447"],
                         security=SecurityConfig(dir=tmp_path))
    assert config.stage_links() == config


class _Counter:
    def __init__(self) -> None:
        self.payloads: list[bytes] = []
        self.cond = threading.Condition()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.payloads.append(bytes(sample.payload))
            self.cond.notify_all()

    def wait_for(self, payload: bytes, timeout: float = 20.0) -> list[bytes]:
        with self.cond:
            assert self.cond.wait_for(lambda: payload in self.payloads, timeout), f"{payload!r} never arrived"
            return list(self.payloads)


def _wait_linked(session: zenoh.Session, other: zenoh.Session, timeout: float = 20.0) -> None:
    """Until `session` has a transport of its own to `other` (a peer link, not the router)."""
    linked = threading.Event()
    other_id = str(other.info.zid())

    def on_event(event: zenoh.TransportEvent) -> None:
        if event.kind == zenoh.SampleKind.PUT and str(event.transport.zid) == other_id:
            linked.set()

    listener = session.info.declare_transport_events_listener(on_event, history=True)
    try:
        assert linked.wait(timeout), "the two stages never linked up directly"
    finally:
        listener.undeclare()


@pytest.mark.integration
def test_stages_exchange_data_directly_once_each_and_a_tool_still_sees_it_through_the_router() -> None:
    port = free_port()
    router = start_router(port)
    stage = ZenohConfig(connect=[endpoint(port)], open_retry_s=0.1, open_retry_max_s=0.3).stage_links()
    sessions: list[zenoh.Session] = []
    try:
        publisher_side, subscriber_side = (open_session(stage) for _ in range(2))
        tool = open_session(ZenohConfig(connect=[endpoint(port)]))  # a monitor or recorder: a client
        sessions += [s for s in (publisher_side, subscriber_side, tool) if s is not None]
        assert publisher_side is not None and subscriber_side is not None and tool is not None
        at_stage, at_tool = _Counter(), _Counter()
        subscriber_side.declare_subscriber(KEY, at_stage)
        tool.declare_subscriber(KEY, at_tool)
        _wait_linked(publisher_side, subscriber_side)
        publisher = publisher_side.declare_publisher(KEY)
        # Until each subscriber is known to the publisher, puts may go nowhere: repeat a probe until both saw it.
        probe_seen = threading.Event()
        threading.Thread(target=lambda: (at_stage.wait_for(b"probe"), at_tool.wait_for(b"probe"), probe_seen.set()),
                         daemon=True).start()
        while not probe_seen.wait(0.05):
            publisher.put(b"probe")
        before = len(at_stage.wait_for(b"probe"))
        for i in range(20):
            publisher.put(f"m{i}".encode())
        publisher.put(b"end")
        at_tool.wait_for(b"end")  # the router's copy has gone out: a duplicate to the stage would be on its way
        got = at_stage.wait_for(b"end")[before:]
        assert got == [f"m{i}".encode() for i in range(20)] + [b"end"]  # once each, in order
        router.stop()
        publisher.put(b"after the router")  # only a direct link can still carry it
        at_stage.wait_for(b"after the router")
    finally:
        for session in sessions:
            session.close()
        router.stop()

"""The hand-off from zenoh's callback thread to a stage's worker: bounded per topic, every payload counted."""
from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from courtloc.common.bus import ZenohConfig
from courtloc.common.inbox import Inbox
from courtloc.common.runtime import Service
from courtloc.common.services_table import SERVICES, TOPICS


def _taken(inbox: Inbox) -> list[tuple[str, object]]:
    out = []
    while (delivery := inbox.take(timeout=0.0)) is not None:
        out.append((delivery.topic_path, delivery.payload))
    return out


def test_a_topic_kept_two_deep_rides_out_one_late_take_and_drops_the_oldest_beyond() -> None:
    inbox = Inbox({"frame": 2})
    inbox.put("frame", 1)
    inbox.put("frame", 2)
    assert inbox.dropped == 0
    inbox.put("frame", 3)
    assert (inbox.received, inbox.dropped) == (3, 1)
    assert _taken(inbox) == [("frame", 2), ("frame", 3)]


def test_a_topic_kept_one_deep_is_replaced_in_its_place() -> None:
    # Odometry that came before a frame is taken before it, newest: fusion needs the motion up to the frame.
    inbox = Inbox({"frame": 2, "odometry": 1})
    inbox.put("odometry", "o1")
    inbox.put("frame", "f1")
    inbox.put("odometry", "o2")
    assert _taken(inbox) == [("odometry", "o2"), ("frame", "f1")]
    assert (inbox.dropped, inbox.superseded) == (1, 0)


def test_a_superseding_topic_replaced_is_counted_apart_from_the_drops() -> None:
    """The newest odometry carries all an older one did: replacing it loses nothing, and the stage's drops say so."""
    inbox = Inbox({"frame": 1, "odometry": 1}, superseding=["odometry"])
    for path, payload in (("odometry", "o1"), ("frame", "f1"), ("odometry", "o2"), ("odometry", "o3")):
        inbox.put(path, payload)
    assert (inbox.received, inbox.dropped, inbox.superseded) == (4, 0, 2)
    inbox.put("frame", "f2")
    assert (inbox.dropped, inbox.superseded) == (1, 2)
    assert _taken(inbox) == [("odometry", "o3"), ("frame", "f2")]


def test_a_superseding_topic_kept_deeper_than_one_is_refused() -> None:
    with pytest.raises(ValueError, match="one deep"):
        Inbox({"odometry": 2}, superseding=["odometry"])


def test_depths_count_per_topic_and_free_up_as_taken() -> None:
    inbox = Inbox({"frame": 2})
    inbox.put("frame", 1)
    inbox.put("health", "h1")  # not named: one deep
    inbox.put("frame", 2)
    assert inbox.take(timeout=0.0).payload == 1
    inbox.put("frame", 3)  # one frame was taken: room for this one
    inbox.put("health", "h2")
    assert inbox.dropped == 1
    assert _taken(inbox) == [("health", "h2"), ("frame", 2), ("frame", 3)]


def test_take_waits_for_a_put_from_another_thread_and_times_out_without_one() -> None:
    inbox = Inbox()
    assert inbox.take(timeout=0.01) is None
    started = threading.Event()

    def put_later() -> None:
        started.wait()
        inbox.put("frame", "late")

    thread = threading.Thread(target=put_later)
    thread.start()
    started.set()
    delivery = inbox.take(timeout=10.0)
    thread.join()
    assert delivery is not None and delivery.payload == "late"


def test_a_depth_below_one_is_refused() -> None:
    with pytest.raises(ValueError, match="depths"):
        Inbox({"frame": 0})


def test_a_stage_keeps_its_inputs_as_deep_as_the_services_table_says() -> None:
    class Probe(Service):
        name = "infer"

    probe = Probe("robot1", ZenohConfig())
    edges, odometry = "preprocess/edges", "shooter_bridge/odometry"
    assert set(SERVICES["infer"].inputs) == {edges, odometry}
    assert TOPICS[edges].inbox_depth == 2 and TOPICS[odometry].inbox_depth == 1
    assert TOPICS[odometry].newest_supersedes and not TOPICS[edges].newest_supersedes
    callbacks = {path: probe._make_callback(path) for path in (edges, odometry)}
    for path, payload in ((edges, "e1"), (odometry, "o1"), (edges, "e2"), (odometry, "o2"), (edges, "e3")):
        callbacks[path](SimpleNamespace(payload=payload))
    assert (probe._inbox.dropped, probe._inbox.superseded) == (1, 1)
    assert _taken(probe._inbox) == [(odometry, "o2"), (edges, "e2"), (edges, "e3")]

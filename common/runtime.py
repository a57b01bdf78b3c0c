"""The service runtime shared by every stage.

A stage subclasses `Service` and implements `on_message` (consumers) or `produce` (sources). The
runtime owns everything else: the Zenoh session (opened with back-off, always closed), a liveliness
token, publishers with the table's QoS, subscriptions handed to the worker thread through a bounded inbox
(each topic as deep as the table says), decoding with per-topic rejection counts, the stage's controls
(queryables of the services table, answered by `on_control` on their own thread), a health message every
second, and SIGINT/SIGTERM.
"""
from __future__ import annotations

import gc
import logging
import threading
import time
from typing import Any, ClassVar

import zenoh
from pydantic import BaseModel

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, declare_publisher, open_session, watch_router_identity
from courtloc.common.control_server import ControlServer
from courtloc.common.inbox import Delivery, Inbox
from courtloc.common.limits import clip_text
from courtloc.common.messages import Header, Health
from courtloc.common.services_table import CONTROLS, HEALTH_TOPICS, SERVICES, TOPICS, Control, Topic, liveliness_key
from courtloc.common.signals import stop_on_signals
from courtloc.common.stats import LatencyWindow, RateLimitedLog, RateMeter

HEALTH_PERIOD_S = 1.0
# A stage that found itself connected to another pipeline's router exits with this code (not 1: no router;
# not 2: a bad deployment) so the launcher restarts it and its log says why.
FOREIGN_ROUTER_EXIT = 3


class Service:
    """Base of every stage process. Subclasses set `name` (a key of SERVICES)."""

    name: ClassVar[str]
    # Inputs that only feed state (e.g. odometry into infer's filter): not timed as the stage's latency.
    side_inputs: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig) -> None:
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.spec = SERVICES[self.name]
        self.log = logging.getLogger(f"courtloc.{self.name}")
        self.stop_event = threading.Event()
        self.session: zenoh.Session | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._inbox = Inbox({path: TOPICS[path].inbox_depth for path in self.spec.inputs},
                            superseding=[path for path in self.spec.inputs if TOPICS[path].newest_supersedes])
        self._started = time.monotonic()
        self._rate_log = RateLimitedLog(self.log)
        self.health_period_s = HEALTH_PERIOD_S  # the deployment's health_period_s (stage_main sets it)
        # The id of the router `courtloc up` started for this run (stage_main sets it from --expect-router);
        # None: any router at the endpoint will do (`courtloc run` joining a robot from the pit).
        self.expected_router_id: str | None = None
        self.foreign_router_id: str | None = None
        self.frames_in = 0
        self.frames_out = 0
        self.stale = 0
        self.extra_dropped = 0
        self.rejected: dict[str, int] = {}  # per input topic
        self.rejected_by_reason: dict[str, int] = {}
        self.published: dict[str, int] = {}
        self.last_error = ""
        self._latency = LatencyWindow()
        self._e2e = LatencyWindow()
        self._rate_in, self._rate_out = RateMeter(), RateMeter()

    # ---- hooks for subclasses -------------------------------------------------------------
    def on_start(self) -> None:
        """After the session and publishers exist, before any message is handled."""

    def on_message(self, topic: Topic, message: Any, delivery: Delivery) -> None:
        """Handle the newest message of an input topic (worker thread)."""

    def produce(self) -> None:
        """Source services override this: loop until `self.stop_event` is set (worker thread)."""
        self._consume()

    def on_control(self, control: Control, request: BaseModel) -> BaseModel:
        """Answer a request to one of this stage's controls (control thread); returns `control.reply`."""
        raise NotImplementedError(f"{self.name} serves no control {control.path}")

    def on_stop(self) -> None:
        """Release devices and files; the session is still open."""

    def health_detail(self) -> dict[str, float | int | str]:
        return {}

    def decode_input(self, topic: Topic, payload: Any) -> Any:
        """Payload -> message (worker thread); a stage that reads only part of a big message overrides it."""
        return codec.decode(bytes(payload), topic.message)

    # ---- helpers for subclasses -------------------------------------------------------------
    def publish(self, topic_path: str, message: BaseModel) -> None:
        self._publishers[topic_path].put(codec.encode(message))
        self.count_published(topic_path, message)

    def publisher(self, topic_path: str) -> zenoh.Publisher:
        """The declared publisher of an output, for a stage that writes its payload itself (shared memory)."""
        return self._publishers[topic_path]

    def count_published(self, topic_path: str, message: BaseModel) -> None:
        self.published[topic_path] = self.published.get(topic_path, 0) + 1
        if topic_path == self.spec.outputs[0]:
            self.frames_out += 1
        header = getattr(message, "header", None)
        if isinstance(header, Header) and header.valid:
            self._e2e.add(header.span_ns())

    def is_fresh(self, header: Header, topic: Topic) -> bool:
        """Counts and reports stale inputs: older than the table's freshness budget, or from the future."""
        fresh = header.is_fresh(topic.freshness_ms * 1e6)
        if not fresh:
            self.stale += 1
        return fresh

    def record_error(self, kind: str, message: str, exc_info: bool = False) -> None:
        """Remember and log (at most one line per kind every few seconds) an error; hostile input echoed
        in `message` is clipped, so it never makes health messages or the log grow."""
        self.last_error = clip_text(message)
        self._rate_log.warning(kind, self.last_error, exc_info=exc_info)

    def reject(self, topic_path: str, reason: str, detail: str, exc_info: bool = False) -> None:
        """Count a bad input with its reason; the service goes on."""
        self.rejected[topic_path] = self.rejected.get(topic_path, 0) + 1
        self.rejected_by_reason[reason] = self.rejected_by_reason.get(reason, 0) + 1
        self.record_error(f"reject:{topic_path}:{reason}", f"rejected {topic_path}: {reason}: {detail}", exc_info)

    def record_latency(self, duration_ns: int) -> None:
        self._latency.add(duration_ns)

    # ---- the runtime --------------------------------------------------------------------
    def run(self) -> int:
        """Run until SIGINT/SIGTERM; returns the process exit code."""
        stop_on_signals(self.stop_event)
        self.session = open_session(self.zenoh_config.stage_links(), self.stop_event)
        if self.session is None:
            return 0
        guard = None
        try:
            if self.expected_router_id is not None:
                guard = watch_router_identity(self.session, self.expected_router_id, self._on_foreign_router)
            code = self._run_in_session(self.session) if not self.stop_event.is_set() else 0
            return FOREIGN_ROUTER_EXIT if self.foreign_router_id is not None else code
        finally:
            if guard is not None:
                guard.undeclare()
            self.session.close()
            self.log.info("%s stopped", self.name)

    def _on_foreign_router(self, router_id: str) -> None:
        """Connected to a router that is not the one `courtloc up` started (zenoh thread): leave at once, so
        this stage's data never mixes with another pipeline's; the launcher restarts it until its own router
        is back. Said once: zenoh may report the same router again while the stage stops."""
        if self.foreign_router_id is None:
            self.foreign_router_id = router_id
            self.log.error("connected to router %s, not %s (the router courtloc up started for this run): another "
                           "pipeline's router holds the endpoint; stopping", router_id, self.expected_router_id)
        self.stop_event.set()

    def _run_in_session(self, zsession: zenoh.Session) -> int:
        for path in self.spec.outputs:
            self._publishers[path] = declare_publisher(zsession, TOPICS[path], self.robot_id)
        health_topic = HEALTH_TOPICS[self.name]
        self._publishers[health_topic.path] = declare_publisher(zsession, health_topic, self.robot_id)
        self.on_start()
        own_controls = [c for c in CONTROLS.values() if c.service == self.name]
        controls = ControlServer(zsession, own_controls, self.robot_id, self.on_control, self.reject,
                                 self.record_error, self.stop_event, f"{self.name}-control") if own_controls else None
        subscribers = [
            zsession.declare_subscriber(TOPICS[path].key(self.robot_id), self._make_callback(path))
            for path in self.spec.inputs
        ]
        # Alive means ready: the token appears only once the stage can take inputs (model loaded,
        # subscribers declared), so whoever waits on it never publishes into the void.
        token = zsession.liveliness().declare_token(liveliness_key(self.robot_id, self.name))
        # Everything allocated so far (model, tables, court field) lives as long as the process: moving it
        # out of the collector's reach keeps full collections from walking it during frames.
        gc.freeze()
        worker = threading.Thread(target=self._work, name=f"{self.name}-worker", daemon=True)
        health = threading.Thread(target=self._health_loop, name=f"{self.name}-health", daemon=True)
        worker.start()
        health.start()
        self.log.info("%s running for robot %s", self.name, self.robot_id)
        while not self.stop_event.wait(0.5):
            if not worker.is_alive():
                self.log.error("worker thread ended unexpectedly; stopping")
                self.stop_event.set()
        self._inbox.wake()
        worker.join(timeout=5.0)
        health.join(timeout=2.0)
        for sub in subscribers:
            sub.undeclare()
        if controls is not None:
            controls.close()
        self.on_stop()
        token.undeclare()
        return 0

    def _make_callback(self, topic_path: str):  # noqa: ANN202 - zenoh callback
        inbox = self._inbox

        def on_sample(sample: zenoh.Sample) -> None:
            inbox.put(topic_path, sample.payload)

        return on_sample

    def _work(self) -> None:
        try:
            self.produce()
        except Exception as exc:  # a bug must not leave a zombie process: log, and let run() stop
            self.log.exception("worker failed")
            self.last_error = clip_text(repr(exc))  # like every string of a health message: bounded
            self.stop_event.set()

    def _consume(self) -> None:
        while not self.stop_event.is_set():
            delivery = self._inbox.take(timeout=0.5)
            if delivery is None:
                continue
            self.frames_in += 1
            topic = TOPICS[delivery.topic_path]
            try:
                codec.check_size(len(delivery.payload), topic.max_bytes)  # before copying it
                message = self.decode_input(topic, delivery.payload)
            except codec.DecodeError as exc:
                self.reject(delivery.topic_path, exc.reason, exc.detail)
                continue
            finally:
                delivery.payload = None  # decoding copied what it needs: a shared-memory buffer goes back now
            if getattr(message, "header", None) is not None and message.header.robot_id != self.robot_id:
                self.reject(delivery.topic_path, "robot_id", f"message for {message.header.robot_id!r}")
                continue
            start = time.perf_counter_ns()
            try:
                self.on_message(topic, message, delivery)
            except Exception as exc:  # one bad input must not kill the stage, nor flood the log
                self.reject(delivery.topic_path, "handler_error", f"{type(exc).__name__}: {exc}", exc_info=True)
                continue
            if delivery.topic_path not in self.side_inputs:
                self.record_latency(time.perf_counter_ns() - start)

    def _health_loop(self) -> None:
        while not self.stop_event.wait(self.health_period_s):
            try:
                self._publishers[HEALTH_TOPICS[self.name].path].put(codec.encode(self.health()))
            except Exception:  # health must never take the service down
                self.log.exception("health publish failed")

    def health(self) -> Health:
        p50, p99 = self._latency.percentiles_ms()
        e50, e99 = self._e2e.percentiles_ms()
        detail: dict[str, float | int | str] = {f"rejected.{k}": v for k, v in self.rejected.items()}
        detail.update({f"reject.{k}": v for k, v in self.rejected_by_reason.items()})
        detail.update({f"published.{k}": v for k, v in self.published.items()})
        # Whether the direct links came up (docs/deployment.md): the peers this session is linked to.
        detail["superseded"] = self._inbox.superseded
        detail["links"] = "direct" if self.zenoh_config.stage_links().mode == "peer" else "router"
        detail["zenoh_peers"] = len(list(self.session.info.peers_zid())) if self.session is not None else 0
        detail.update(self.health_detail())
        detail = {k: clip_text(v) if isinstance(v, str) else v for k, v in detail.items()}
        return Health(
            robot_id=self.robot_id, service=self.name, uptime_s=time.monotonic() - self._started,
            rate_in_hz=self._rate_in.rate(self.frames_in), rate_out_hz=self._rate_out.rate(self.frames_out),
            frames_in=self.frames_in, frames_out=self.frames_out,
            dropped=self._inbox.dropped + self.extra_dropped, rejected=sum(self.rejected.values()),
            stale=self.stale, latency_ms_p50=p50, latency_ms_p99=p99, e2e_ms_p50=e50, e2e_ms_p99=e99,
            last_error=self.last_error, detail=detail,
        )

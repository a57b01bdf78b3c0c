"""The service runtime shared by every stage.

A stage subclasses `Service` and implements `on_message` (consumers) or `produce` (sources). The
runtime owns everything else: the Zenoh session (opened with back-off, always closed), a liveliness
token, publishers with the table's QoS, latest-only subscriptions handed to the worker thread,
decoding with per-topic rejection counts, a health message every second, and SIGINT/SIGTERM.
"""
from __future__ import annotations

import gc
import logging
import signal
import threading
import time
from typing import Any, ClassVar

import zenoh
from pydantic import BaseModel

from courtloc.common import codec
from courtloc.common.bus import ZenohConfig, declare_publisher, open_session
from courtloc.common.inbox import Delivery, LatestInbox
from courtloc.common.messages import Header, Health
from courtloc.common.services_table import HEALTH_TOPICS, SERVICES, TOPICS, Topic, liveliness_key
from courtloc.common.stats import LatencyWindow, RateLimitedLog, RateMeter

HEALTH_PERIOD_S = 1.0


class Service:
    """Base of every stage process. Subclasses set `name` (a key of SERVICES)."""

    name: ClassVar[str]

    def __init__(self, robot_id: str, zenoh_config: ZenohConfig) -> None:
        self.robot_id = robot_id
        self.zenoh_config = zenoh_config
        self.spec = SERVICES[self.name]
        self.log = logging.getLogger(f"courtloc.{self.name}")
        self.stop_event = threading.Event()
        self.session: zenoh.Session | None = None
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._inbox = LatestInbox()
        self._started = time.monotonic()
        self._rate_log = RateLimitedLog(self.log)
        self.frames_in = 0
        self.frames_out = 0
        self.stale = 0
        self.extra_dropped = 0
        self.rejected: dict[str, int] = {}
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
        """Counts and reports stale inputs: older than the table's freshness budget."""
        fresh = header.age_ns() <= topic.freshness_ms * 1e6
        if not fresh:
            self.stale += 1
        return fresh

    def record_error(self, kind: str, message: str) -> None:
        self.last_error = message
        self._rate_log.warning(kind, message)

    def reject(self, topic_path: str, reason: str, detail: str) -> None:
        """Count a bad input; the service goes on."""
        self.rejected[topic_path] = self.rejected.get(topic_path, 0) + 1
        self.record_error(f"reject:{topic_path}:{reason}", f"rejected {topic_path}: {reason}: {detail}")

    def record_latency(self, duration_ns: int) -> None:
        self._latency.add(duration_ns)

    # ---- the runtime --------------------------------------------------------------------
    def run(self) -> int:
        """Run until SIGINT/SIGTERM; returns the process exit code."""
        self._install_signal_handlers()
        self.session = open_session(self.zenoh_config, self.stop_event)
        if self.session is None:
            return 0
        try:
            return self._run_in_session(self.session)
        finally:
            self.session.close()
            self.log.info("%s stopped", self.name)

    def _run_in_session(self, zsession: zenoh.Session) -> int:
        for path in self.spec.outputs:
            self._publishers[path] = declare_publisher(zsession, TOPICS[path], self.robot_id)
        health_topic = HEALTH_TOPICS[self.name]
        self._publishers[health_topic.path] = declare_publisher(zsession, health_topic, self.robot_id)
        self.on_start()
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
            self.last_error = repr(exc)
            self.stop_event.set()

    def _consume(self) -> None:
        while not self.stop_event.is_set():
            delivery = self._inbox.take(timeout=0.5)
            if delivery is None:
                continue
            self.frames_in += 1
            topic = TOPICS[delivery.topic_path]
            try:
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
            except Exception as exc:  # one bad frame must not kill the stage
                self.log.exception("handling %s failed", delivery.topic_path)
                self.record_error("handler", f"{type(exc).__name__}: {exc}")
                continue
            self.record_latency(time.perf_counter_ns() - start)

    def _health_loop(self) -> None:
        while not self.stop_event.wait(HEALTH_PERIOD_S):
            try:
                self._publishers[HEALTH_TOPICS[self.name].path].put(codec.encode(self.health()))
            except Exception:  # health must never take the service down
                self.log.exception("health publish failed")

    def health(self) -> Health:
        p50, p99 = self._latency.percentiles_ms()
        e50, e99 = self._e2e.percentiles_ms()
        detail: dict[str, float | int | str] = {f"rejected.{k}": v for k, v in self.rejected.items()}
        detail.update({f"published.{k}": v for k, v in self.published.items()})
        detail.update(self.health_detail())
        return Health(
            robot_id=self.robot_id, service=self.name, uptime_s=time.monotonic() - self._started,
            rate_in_hz=self._rate_in.rate(self.frames_in), rate_out_hz=self._rate_out.rate(self.frames_out),
            frames_in=self.frames_in, frames_out=self.frames_out,
            dropped=self._inbox.dropped + self.extra_dropped, rejected=sum(self.rejected.values()),
            stale=self.stale, latency_ms_p50=p50, latency_ms_p99=p99, e2e_ms_p50=e50, e2e_ms_p99=e99,
            last_error=self.last_error, detail=detail,
        )

    def _install_signal_handlers(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def request_stop(signum: int, _frame: object) -> None:
            self.log.info("signal %d: shutting down", signum)
            self.stop_event.set()

        signal.signal(signal.SIGINT, request_stop)
        signal.signal(signal.SIGTERM, request_stop)

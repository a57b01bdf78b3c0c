"""Wires the monitor together: bus watcher, thumbnail thread, state ticker and web server."""
from __future__ import annotations

import json
import logging
import threading
import time

from courtloc.monitor.server import Broadcast, MonitorServer
from courtloc.monitor.state import Snapshotter, court_payload
from courtloc.monitor.thumbnail import Thumbnailer
from courtloc.monitor.watcher import MonitorWatcher
from courtloc.services.deployment import DeploymentConfig
from courtloc.world.court import load_court

log = logging.getLogger("courtloc.monitor")


class Monitor:
    def __init__(self, config: DeploymentConfig, court_name: str, host: str, port: int, rate_hz: float = 15.0,
                 thumb_width: int = 320, thumb_rate_hz: float = 5.0) -> None:
        self.config = config
        self.rate_hz = rate_hz
        self.stop = threading.Event()
        self.watcher = MonitorWatcher(config)
        self.thumbnailer = Thumbnailer(self.watcher, thumb_width, thumb_rate_hz)
        self.snapshotter = Snapshotter(self.watcher, self.thumbnailer)
        self.broadcast = Broadcast()
        court_json = json.dumps(court_payload(load_court(court_name))).encode()
        self.server = MonitorServer((host, port), self.broadcast, court_json, self._thumbnail_jpeg, self.stop)
        self._threads: list[threading.Thread] = []

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}/"

    def _thumbnail_jpeg(self) -> bytes | None:
        thumb = self.thumbnailer.latest
        return None if thumb is None else thumb.jpeg

    def _tick(self) -> None:
        period = 1.0 / self.rate_hz
        next_due = time.monotonic()
        while not self.stop.is_set():
            try:
                self.broadcast.publish(self.snapshotter.snapshot())
            except Exception as exc:  # a bug here must show on the page, not freeze it
                log.exception("state snapshot failed")
                self.broadcast.publish({"status": "error", "error": f"monitor: {type(exc).__name__}: {exc}"})
            next_due += period
            if self.stop.wait(max(0.0, next_due - time.monotonic())):
                break

    def run(self, stop: threading.Event) -> None:
        """Serve until `stop` is set; everything is closed on the way out."""
        self.watcher.start(self.stop)
        self._threads = [
            self.thumbnailer.start(self.stop),
            threading.Thread(target=self._tick, name="monitor-tick", daemon=True),
            threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.25},
                             name="monitor-http", daemon=True),
        ]
        for thread in self._threads[1:]:
            thread.start()
        try:
            stop.wait()
        finally:
            self.stop.set()
            self.broadcast.wake_all()
            self.server.shutdown()
            self.server.server_close()
            for thread in self._threads:
                thread.join(timeout=3.0)
            self.watcher.close()

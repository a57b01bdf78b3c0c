"""`courtloc up`: a router and every configured stage as separate OS processes, supervised.

The launcher restarts a stage that dies (with back-off that resets once the stage has run healthily
for a while; the router with a short one, since every stage waits on it), watches the bus as a client
to print one live status line, and writes a JSON summary on exit.

It refuses to start when its router cannot listen (the port is taken, e.g. by another pipeline):
stages started anyway would join that pipeline's router under the same robot id and mix its data.
Later, when its router dies and another pipeline's router takes the port before ours is back, the stages
(clients reconnecting to the same endpoint) must not join that one either: the router gets a zenoh id of
this run, and each stage exits when connected to a router with another id (`--expect-router`).
"""
from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO, TextIO

from courtloc.common.bus import new_router_id
from courtloc.port_holder import endpoint_port, port_holder
from courtloc.router_process import router_argv
from courtloc.services.deployment import DeploymentConfig
from courtloc.stage_cli import router_settings, stage_argv
from courtloc.watch import BusWatcher

log = logging.getLogger("courtloc.launcher")


class LaunchError(RuntimeError):
    """The pipeline cannot start as configured; the message says why in one line."""


@dataclass
class Child:
    name: str
    argv: list[str]  # a restart's command line
    backoff_s: float
    backoff_max_s: float = 5.0
    process: subprocess.Popen | None = None
    restarts: int = 0
    next_start: float = 0.0
    started_at: float = 0.0
    log_path: Path | None = None

    ready_line: str | None = None
    ready: threading.Event = field(default_factory=threading.Event)
    settled: threading.Event = field(default_factory=threading.Event)  # ready, or the output ended
    last_line: str = ""
    first_argv: list[str] | None = None  # the first start's, when it differs (a fresh run)

    def __post_init__(self) -> None:
        self.initial_backoff_s = self.backoff_s

    def start(self, log_dir: Path, now: float | None = None) -> None:
        self.log_path = log_dir / f"{self.name}.log"
        self.started_at = time.monotonic() if now is None else now
        self.ready.clear()
        self.settled.clear()
        handle = self.log_path.open("ab")
        argv = self.first_argv if self.restarts == 0 and self.first_argv is not None else self.argv
        if self.ready_line is None:
            self.process = subprocess.Popen(argv, stdout=handle, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL)
            handle.close()
            self.ready.set()
            self.settled.set()
            return
        self.process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL)
        threading.Thread(target=self._pump, args=(handle,), daemon=True).start()

    def _pump(self, handle: BinaryIO) -> None:
        """Copy the child's output to its log, and notice the line that says it is ready."""
        assert self.process is not None and self.process.stdout is not None
        with handle:
            for line in self.process.stdout:
                handle.write(line)
                handle.flush()
                if line.strip():
                    self.last_line = line.decode(errors="replace").strip()
                if self.ready_line is not None and self.ready_line.encode() in line:
                    self.ready.set()
                    self.settled.set()
        self.settled.set()

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def stop(self, timeout: float) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        self.process.terminate()
        try:
            self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            log.warning("%s did not stop in %.0f s; killing it", self.name, timeout)
            self.process.kill()
            self.process.wait()


@dataclass
class Supervisor:
    config: DeploymentConfig
    config_path: Path
    log_dir: Path
    children: list[Child] = field(default_factory=list)

    def __post_init__(self) -> None:
        launcher = self.config.launcher
        # Our router's identity, new each run and kept across its restarts: a stage connected to a router with
        # another id (another pipeline's, which took the port while ours was down) exits, and is restarted until
        # ours is back. Only for client stages: a client has exactly one router, while a peer may also link to
        # routers ours is connected to ([router] connect) by gossip.
        self.router_id = new_router_id() if launcher.run_router else None
        expect = self.router_id if self.config.zenoh.mode == "client" else None
        if launcher.run_router:
            self.children.append(Child("router", router_argv(router_settings(self.config, zenoh_id=self.router_id)),
                                       launcher.router_restart_backoff_s, launcher.restart_backoff_s,
                                       ready_line="router listening"))
        for name in launcher.services:
            # The first start is a new run (a pose saved by an earlier run is not its evidence); a restart
            # resumes mid-run from the pose its predecessor saved.
            self.children.append(Child(name, stage_argv(name, self.config_path, self.config, expect_router=expect),
                                       launcher.restart_backoff_s, launcher.restart_backoff_max_s,
                                       first_argv=stage_argv(name, self.config_path, self.config, fresh_run=True,
                                                             expect_router=expect)))

    def start_all(self, ready_timeout_s: float = 15.0) -> None:
        """The router first: stages started after it is listening connect at once. A router that does
        not come up stops the launch (LaunchError): nothing else is started."""
        for child in self.children:
            child.start(self.log_dir)
            child.settled.wait(ready_timeout_s)
            if child.ready.is_set():
                continue
            if child.name == "router":
                child.stop(timeout=2.0)
                raise LaunchError(self._router_failure(child, ready_timeout_s))
            log.warning("%s not ready after %.0f s (see %s)", child.name, ready_timeout_s, child.log_path)

    def _router_failure(self, child: Child, waited_s: float) -> str:
        why = child.last_line or f"not listening after {waited_s:.0f} s"
        holders = []
        for endpoint in self.config.router.listen:
            port = endpoint_port(endpoint)
            holder = port_holder(port) if port is not None else None
            if holder is not None:
                holders.append(f"port {port} is held by {holder}")
        return (f"router cannot listen on {', '.join(self.config.router.listen)}: "
                f"{'; '.join(holders) or why}; not starting the stages (they would join whatever "
                f"router answers there; set [launcher] run_router = false to join an existing one)")

    def check(self, now: float | None = None) -> None:
        """Restart dead children with exponential back-off per child; a child that has run for
        `restart_healthy_s` is healthy again and its next restart starts from the first delay."""
        now = time.monotonic() if now is None else now
        healthy_s = self.config.launcher.restart_healthy_s
        for child in self.children:
            if child.alive():
                if child.backoff_s != child.initial_backoff_s and now - child.started_at >= healthy_s:
                    child.backoff_s = child.initial_backoff_s
                continue
            if child.next_start == 0.0:
                code = child.process.returncode if child.process else None
                if now - child.started_at >= healthy_s:  # it ran healthily until it died
                    child.backoff_s = child.initial_backoff_s
                log.warning("%s exited (code %s); restarting in %.1f s (see %s)", child.name, code,
                            child.backoff_s, child.log_path)
                child.next_start = now + child.backoff_s
            if now >= child.next_start:
                child.restarts += 1
                child.start(self.log_dir, now)
                child.next_start = 0.0
                child.backoff_s = min(child.backoff_s * 2, child.backoff_max_s)

    def stop_all(self) -> None:
        # Stages first, so none of them sees its router vanish while shutting down.
        for child in reversed(self.children):
            child.stop(timeout=8.0)

    def restarts(self) -> dict[str, int]:
        return {c.name: c.restarts for c in self.children}


def write_effective_config(config: DeploymentConfig, folder: Path) -> Path:
    path = folder / "deployment.json"
    path.write_text(config.model_dump_json(indent=2))
    return path


def run_up(config: DeploymentConfig, duration_s: float | None, summary_path: Path | None,
           stop: threading.Event, status_stream: TextIO = sys.stderr) -> dict:
    with tempfile.TemporaryDirectory(prefix="courtloc-up-") as tmp:
        folder = Path(tmp)
        log_dir = Path(os.environ.get("COURTLOC_LOG_DIR", folder))
        log_dir.mkdir(parents=True, exist_ok=True)
        supervisor = Supervisor(config, write_effective_config(config, folder), log_dir)
        try:
            supervisor.start_all()
        except LaunchError:
            supervisor.stop_all()
            raise
        watcher = BusWatcher(config)
        watcher.start(stop)
        started = time.monotonic()
        live = status_stream.isatty()
        last_status = 0.0
        try:
            while not stop.wait(0.1):  # a dead router is noticed (and restarted) within this
                supervisor.check()
                now = time.monotonic()
                if live:
                    status_stream.write("\r" + watcher.status_line() + " " * 4)
                    status_stream.flush()
                elif now - last_status >= 5.0:  # a log, not a terminal: one line every few seconds
                    status_stream.write(watcher.status_line() + "\n")
                    status_stream.flush()
                    last_status = now
                if duration_s is not None and now - started >= duration_s:
                    break
        finally:
            if live:
                status_stream.write("\n")
            watcher.close()
            supervisor.stop_all()
        summary = watcher.summary(supervisor.restarts(), time.monotonic() - started)
    if summary_path is not None:
        summary_path.write_text(json.dumps(summary, indent=2))
    return summary

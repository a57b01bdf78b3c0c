"""Serving a stage's controls (the services table's queryables) off Zenoh's callback thread.

The callback only queues the query; a thread of our own per control decodes the request, asks the
stage's handler and replies, so a slow request (a model validation) never blocks Zenoh nor another
control (a pose set while a push validates), and a bad request is counted like any bad message.
"""
from __future__ import annotations

import logging
import queue
import threading
from typing import Callable

import zenoh
from pydantic import BaseModel

from courtloc.common import codec
from courtloc.common.services_table import Control

log = logging.getLogger(__name__)
_QUEUE_DEPTH = 64
_POLL_S = 0.5  # how often the serving thread looks at the stop event while idle

Handler = Callable[[Control, BaseModel], BaseModel]


class ControlServer:
    def __init__(self, session: zenoh.Session, controls: list[Control], robot_id: str, handler: Handler,
                 reject: Callable[..., None], record_error: Callable[[str, str], None],
                 stop: threading.Event, thread_name: str) -> None:
        self._handler = handler
        self._reject = reject
        self._record_error = record_error
        self._stop = stop
        self._queues = {c.path: queue.Queue(maxsize=_QUEUE_DEPTH) for c in controls}
        self._queryables = [session.declare_queryable(c.key(robot_id), self._enqueue(c)) for c in controls]
        self._threads = [threading.Thread(target=self._serve, args=(c,), name=f"{thread_name}-{c.name}", daemon=True)
                         for c in controls]
        for thread in self._threads:
            thread.start()

    def _enqueue(self, control: Control) -> Callable[[zenoh.Query], None]:
        requests = self._queues[control.path]

        def on_query(query: zenoh.Query) -> None:
            try:
                requests.put_nowait(query)
            except queue.Full:  # dropped: the caller's request times out and it may ask again
                self._record_error("control", f"{control.path}: request queue full; request dropped")

        return on_query

    def _serve(self, control: Control) -> None:
        requests = self._queues[control.path]
        while not self._stop.is_set():
            try:
                query = requests.get(timeout=_POLL_S)
            except queue.Empty:
                continue
            # Dropping the query finalises it; until then the asker does not get the reply (a query kept
            # alive in a loop variable would hold it until the next request arrived).
            with query:
                self._answer(control, query)

    def _answer(self, control: Control, query: zenoh.Query) -> None:
        payload = query.payload
        try:
            codec.check_size(len(payload) if payload is not None else 0, control.max_bytes)  # before copying it
            request = codec.decode(bytes(payload) if payload is not None else b"", control.request)
            reply = self._handler(control, request)
        except codec.DecodeError as exc:
            self._reject(control.path, exc.reason, exc.detail)
            reply = control.reply(ok=False, reason=f"bad request: {exc}")
        except Exception as exc:  # a control bug must not stop the stage
            # The exception's text may name files of the stage: it goes to our log, not to the asker.
            self._reject(control.path, "handler_error", f"{type(exc).__name__}: {exc}", exc_info=True)
            reply = control.reply(ok=False, reason=f"internal error ({type(exc).__name__}); see the "
                                                   f"{control.service} log")
        try:
            query.reply(query.key_expr, codec.encode(reply))
        except zenoh.ZError as exc:
            self._record_error("control", f"cannot answer {control.path}: {exc}")

    def close(self) -> None:
        for thread in self._threads:
            thread.join(timeout=5.0)
        for queryable in self._queryables:
            queryable.undeclare()

"""`infer/set_pose`: the pit sets the robot's pose (`courtloc pose set`), answered on a thread of its own.

Its own thread, not the model-control one: a model push can keep that busy validating for seconds, and a
pose set is what the pit does when the robot is waiting. The Zenoh callback only queues the query.
"""
from __future__ import annotations

import logging
import queue
import threading
from typing import Callable

import zenoh

from courtloc.common import codec
from courtloc.common.control import PoseReply, PoseRequest, SetPose
from courtloc.common.services_table import CONTROLS

log = logging.getLogger(__name__)
CONTROL = CONTROLS["infer/set_pose"]


class PoseControl:
    def __init__(self, session: zenoh.Session, robot_id: str, apply: Callable[[SetPose], PoseReply],
                 reject: Callable[[str, str, str], None], stop: threading.Event) -> None:
        self._apply = apply
        self._reject = reject
        self._stop = stop
        self._queries: queue.Queue[zenoh.Query] = queue.Queue(maxsize=16)
        self._queryable = session.declare_queryable(CONTROL.key(robot_id), self._enqueue)
        self._thread = threading.Thread(target=self._serve, name="infer-pose-control", daemon=True)
        self._thread.start()

    def _enqueue(self, query: zenoh.Query) -> None:
        try:
            self._queries.put_nowait(query)
        except queue.Full:  # the asker times out and may ask again
            log.warning("pose request queue full; request dropped")

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                query = self._queries.get(timeout=0.5)  # wakes up to notice a shutdown
            except queue.Empty:
                continue
            with query:  # dropping the query finalises the reply
                self._answer(query)

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload
        try:
            request = codec.decode(bytes(payload) if payload is not None else b"", PoseRequest)
            reply = self._apply(request.body)
        except codec.DecodeError as exc:
            self._reject(CONTROL.path, exc.reason, exc.detail)
            reply = PoseReply(ok=False, reason=f"bad request: {exc}")
        except Exception as exc:  # a control bug must not stop inference
            log.exception("pose control failed")
            reply = PoseReply(ok=False, reason=f"internal error: {type(exc).__name__}: {exc}")
        try:
            query.reply(query.key_expr, codec.encode(reply))
        except zenoh.ZError as exc:
            log.warning("cannot answer a pose request: %s", exc)

    def close(self) -> None:
        self._thread.join(timeout=5.0)
        self._queryable.undeclare()

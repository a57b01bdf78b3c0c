"""Our layout of bus recordings in MCAP files, written with rotation and read back in order.

A recording is a pair of files, so that a Foxglove user's topic list holds only what Foxglove can show:
- `OUT.mcap`, the view (open this in Foxglove, `mcap cat`): per recorded topic a JSON channel (message
  encoding `json`, schema encoding `jsonschema`, schema `courtloc.<Type>` or a Foxglove image schema for
  frames, see jsonview) named like the zenoh key, plus the Foxglove channels of foxview (poses as
  PoseInFrame, TF, the court as a SceneUpdate, hits as image annotations);
- `OUT.exact.mcap`, the exact payloads (message encoding `msgpack`, schema `courtloc.<Type>`, topic =
  the zenoh key): the bytes that were on the bus; replay publishes these, so it is bit-exact. A payload
  that did not decode is kept here only (nothing is lost).
Readers find the exact file next to the view (`exact_path`); a single file that holds both kinds of
channel (recordings made before the split, topics `<key>#msgpack`) is read as well.
Channel metadata `courtloc.path`, `courtloc.robot_id` and `courtloc.view` say what a channel holds,
so readers never parse topic names.
"""
from __future__ import annotations

import json
import logging
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Iterable, Iterator

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.summary import Summary
from mcap.writer import CompressionType, Writer

from courtloc.common.services_table import TOPICS
from courtloc.recording.foxview import FoxgloveViews, TopicView
from courtloc.recording.jsonview import JsonView, schema_data, schema_name

log = logging.getLogger("courtloc.recording")

VIEW_JSON = "json"
VIEW_MSGPACK = "msgpack"
VIEW_FOXGLOVE = "foxglove"
EXACT_SUFFIX = ".exact.mcap"
LIBRARY = "courtloc record"
# Data still in an open chunk is lost if the recorder dies hard (power, SIGKILL): chunks are closed
# at least this often, so a cut-short file loses about a second.
FLUSH_PERIOD_S = 1.0


@dataclass(frozen=True)
class RecordItem:
    """One bus sample as the recorder stores it."""

    path: str  # topic path of the services table, e.g. "infer/pose"
    robot_id: str
    log_time: int  # wall-clock ns when the recorder received it
    publish_time: int  # wall-clock ns when the producer published it (or log_time)
    sequence: int
    raw: bytes  # the exact msgpack payload
    json: JsonView | None  # None when the payload did not decode
    extras: tuple[TopicView, ...] = ()  # Foxglove channels derived from the message (foxview)


@dataclass(frozen=True)
class Limits:
    max_bytes: int | None = None
    max_seconds: float | None = None

    @property
    def rotating(self) -> bool:
        return self.max_bytes is not None or self.max_seconds is not None


def part_path(out: Path, index: int) -> Path:
    return out.with_name(f"{out.stem}-{index:03d}{out.suffix}")


def exact_path(view_file: Path) -> Path:
    """run.mcap -> run.exact.mcap: where the exact payloads of a view file are."""
    return view_file.with_name(view_file.stem + EXACT_SUFFIX)


class _FileWriter:
    """One MCAP file being written; schemas and channels are registered on first use."""

    def __init__(self, path: Path, chunk_size: int, metadata: dict[str, str]) -> None:
        self.path = path
        self.handle: BinaryIO = path.open("wb")
        self.writer = Writer(self.handle, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=LIBRARY)
        self.writer.add_metadata("courtloc", metadata)
        self.chunk_size = chunk_size
        self.schemas: dict[str, int] = {}
        self.schema_bytes = 0
        self.channels: dict[tuple[str, str, str, str], int] = {}
        self._last_pos = self.handle.tell()
        self._pending = 0  # bytes handed to the writer since the file last grew (an open chunk)

    def channel(self, topic: str, path: str, robot_id: str, view: str, schema: str) -> int:
        found = self.channels.get((topic, robot_id, view, schema))
        if found is not None:
            return found
        if schema not in self.schemas:
            data = schema_data(schema)
            self.schemas[schema] = self.writer.register_schema(schema, "jsonschema", data)
            self.schema_bytes += len(data)
        channel_id = self.writer.register_channel(
            topic=topic, message_encoding=VIEW_MSGPACK if view == VIEW_MSGPACK else VIEW_JSON,
            schema_id=self.schemas[schema],
            metadata={"courtloc.path": path, "courtloc.robot_id": robot_id, "courtloc.view": view})
        self.channels[(topic, robot_id, view, schema)] = channel_id
        return channel_id

    def add(self, channel_id: int, item: RecordItem, data: bytes) -> None:
        self.writer.add_message(channel_id, log_time=item.log_time, data=data, publish_time=item.publish_time,
                                sequence=item.sequence)
        self._pending += len(data) + 48  # + record header and its message-index entry
        pos = self.handle.tell()
        if pos != self._last_pos:
            self._last_pos, self._pending = pos, 0

    def flush(self) -> None:
        self.writer.flush()
        self._last_pos, self._pending = self.handle.tell(), 0

    def size_estimate(self) -> int:
        """Bytes on disk, the open chunk uncompressed, and room for the summary `finish` appends.

        The summary repeats schemas and channels and indexes every chunk; the reserve is generous so
        a finished file stays under the limit.
        """
        chunks = self._last_pos // self.chunk_size + 2
        reserve = 2 * self.schema_bytes + 256 * len(self.channels) * (1 + chunks // 8) + 128 * chunks + 4096
        return self._last_pos + self._pending + reserve

    def close(self) -> None:
        self.writer.finish()
        self.handle.close()


class _OpenFile:
    """One part of a recording: the view file and its exact twin, written and rotated together."""

    def __init__(self, path: Path, chunk_size: int, metadata: dict[str, str],
                 foxglove: FoxgloveViews | None) -> None:
        self.path = path
        self.view = _FileWriter(path, chunk_size, metadata)
        self.exact = _FileWriter(exact_path(path), chunk_size, metadata)
        self.foxglove = foxglove
        self.first_log_time: int | None = None
        self.messages = 0
        self.unflushed = 0
        self.flushed_at = time.monotonic()

    def _extra(self, item: RecordItem, view: TopicView) -> None:
        channel = self.view.channel(view.topic, item.path, item.robot_id, VIEW_FOXGLOVE, view.schema_name)
        self.view.add(channel, item, view.data)

    def add(self, item: RecordItem) -> None:
        if self.first_log_time is None:
            self.first_log_time = item.log_time
            if self.foxglove is not None:  # each part opens on its own in Foxglove: each gets the court
                for view in self.foxglove.preamble(item.robot_id, item.log_time):
                    self._extra(item, view)
        key = TOPICS[item.path].key(item.robot_id)
        exact = self.exact.channel(key, item.path, item.robot_id, VIEW_MSGPACK, schema_name(TOPICS[item.path].message))
        self.exact.add(exact, item, item.raw)
        if item.json is not None:
            channel = self.view.channel(key, item.path, item.robot_id, VIEW_JSON, item.json.schema_name)
            self.view.add(channel, item, item.json.data)
        for view in item.extras:
            self._extra(item, view)
        self.messages += 1
        self.unflushed += 1

    def flush_if_due(self, now: float) -> None:
        if self.unflushed and now - self.flushed_at >= FLUSH_PERIOD_S:
            self.view.flush()
            self.exact.flush()
            self.unflushed, self.flushed_at = 0, now

    def size_estimate(self) -> int:
        """The larger of the two files (a size limit applies to each file)."""
        return max(self.view.size_estimate(), self.exact.size_estimate())

    def close(self) -> None:
        self.view.close()
        self.exact.close()


class McapSeries:
    """Writes OUT.mcap (+ OUT.exact.mcap), or OUT-000.mcap, OUT-001.mcap... when a size or duration limit
    is set. `foxglove` adds the Foxglove channels (court scene per file; items carry the others)."""

    def __init__(self, out: Path, limits: Limits, metadata: dict[str, str],
                 foxglove: FoxgloveViews | None = None) -> None:
        self.out = out
        self.foxglove = foxglove
        self.limits = limits
        self.metadata = metadata
        self.files: list[Path] = []
        self._current: _OpenFile | None = None
        budget = limits.max_bytes or 4 << 20
        # Small chunks when the limit is small, so the size estimate stays close to the truth.
        self._chunk_size = max(32 << 10, min(1 << 20, budget // 8))

    def write(self, item: RecordItem) -> None:
        current = self._current
        if current is not None and current.messages and self._full(current, item):
            current.close()
            self._current = current = None
        if current is None:
            path = part_path(self.out, len(self.files)) if self.limits.rotating else self.out
            current = self._current = _OpenFile(path, self._chunk_size, self.metadata, self.foxglove)
            self.files.append(path)
            log.info("recording to %s", path)
        current.add(item)
        current.flush_if_due(time.monotonic())

    def tick(self, now: float | None = None) -> None:
        """Close the open chunk if it is older than FLUSH_PERIOD_S (call when idle, too)."""
        if self._current is not None:
            self._current.flush_if_due(time.monotonic() if now is None else now)

    def _full(self, current: _OpenFile, item: RecordItem) -> bool:
        limits = self.limits
        incoming = max(len(item.raw), (len(item.json.data) if item.json is not None else 0)
                       + sum(len(v.data) for v in item.extras))
        if limits.max_bytes is not None and current.size_estimate() + incoming > limits.max_bytes:
            return True
        return (limits.max_seconds is not None and current.first_log_time is not None
                and item.log_time - current.first_log_time >= limits.max_seconds * 1e9)

    def close(self) -> None:
        if self._current is not None:
            self._current.close()
            self._current = None


# ---- reading ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class Recorded:
    path: str
    robot_id: str
    view: str
    log_time: int
    publish_time: int
    data: bytes


def series_files(path: Path) -> list[Path]:
    """IN.mcap itself, or the parts IN-000.mcap, IN-001.mcap... that `record` wrote with rotation."""
    if path.is_file():
        return [path]
    parts = sorted(path.parent.glob(f"{path.stem}-[0-9][0-9][0-9]{path.suffix}"))
    if not parts:
        raise FileNotFoundError(f"no recording {path} (nor {part_path(path, 0).name}, ...)")
    return parts


def _summary_or_none(handle: BinaryIO) -> Summary | None:
    try:
        return make_reader(handle).get_summary()
    except McapError:
        return None
    finally:
        handle.seek(0)


def _messages(file: Path, handle: BinaryIO) -> Iterator[tuple[Any, Any, Any]]:
    """A finished file in log-time order; a file cut short (recorder killed, disk full) record by record
    up to the cut, in the order written (which is arrival order)."""
    if _summary_or_none(handle) is not None:
        yield from make_reader(handle).iter_messages(log_time_order=True)
        return
    log.warning("%s has no index (recording cut short?): reading it record by record", file)
    count = 0
    try:
        for item in NonSeekingReader(handle).iter_messages(log_time_order=False):
            count += 1
            yield item
    except (McapError, EOFError, struct.error, ValueError) as exc:
        log.warning("%s ends early (%s): %d messages recovered", file, exc, count)


def source_file(file: Path, view: str) -> Path:
    """The file that holds `view`: the exact twin of a view file for msgpack, when it is there."""
    if view == VIEW_MSGPACK and not file.name.endswith(EXACT_SUFFIX) and exact_path(file).is_file():
        return exact_path(file)
    return file


def read_series(files: Iterable[Path], view: str = VIEW_MSGPACK, only: set[str] | None = None) -> Iterator[Recorded]:
    """Messages of one view in log-time order, file after file; only topic paths in `only` when given."""
    for given in files:
        file = source_file(given, view)
        with file.open("rb") as handle:
            for _schema, channel, message in _messages(file, handle):
                meta = channel.metadata
                if meta.get("courtloc.view") != view:
                    continue
                path = meta.get("courtloc.path", "")
                if path not in TOPICS or (only is not None and path not in only):
                    continue
                yield Recorded(path, meta.get("courtloc.robot_id", ""), view, message.log_time,
                               message.publish_time, bytes(message.data))


def recorded_channels(files: Iterable[Path], view: str = VIEW_MSGPACK) -> set[tuple[str, str]]:
    """(topic path, robot id) of every channel of one view, from the files' summaries (no message is read)."""
    found: set[tuple[str, str]] = set()
    for given in files:
        with source_file(given, view).open("rb") as handle:
            summary = _summary_or_none(handle)
        for channel in (summary.channels.values() if summary else ()):
            meta = channel.metadata
            if meta.get("courtloc.view") == view and meta.get("courtloc.path") in TOPICS:
                found.add((meta["courtloc.path"], meta.get("courtloc.robot_id", "")))
    return found


def file_summary(file: Path) -> dict[str, object]:
    """Per-channel message counts and the metadata of a recording (for `replay --info` and tests)."""
    with file.open("rb") as handle:
        summary = _summary_or_none(handle)
        metadata = {m.name: dict(m.metadata) for m in make_reader(handle).iter_metadata()} if summary else {}
    if summary is None:
        return {"file": str(file), "channels": {}, "metadata": {}, "index": "missing (cut short): replay reads "
                "it record by record"}
    counts = summary.statistics.channel_message_counts if summary.statistics else {}
    channels = {ch.topic: {"encoding": ch.message_encoding, "messages": counts.get(ch_id, 0),
                           "schema": summary.schemas[ch.schema_id].name if ch.schema_id in summary.schemas else ""}
                for ch_id, ch in summary.channels.items()}
    return {"file": str(file), "channels": channels, "metadata": metadata,
            "start_ns": summary.statistics.message_start_time if summary.statistics else 0,
            "end_ns": summary.statistics.message_end_time if summary.statistics else 0}


def dumps_summary(files: list[Path]) -> str:
    """The summaries of the view files and of their exact twins."""
    every = [g for f in files for g in (f, exact_path(f)) if g == f or g.is_file()]
    return json.dumps([file_summary(f) for f in every], indent=2)

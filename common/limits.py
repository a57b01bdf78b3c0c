"""The contract's size limits: every bus message is bounded before it is decoded or used.

The message models (`messages.py`, `control.py`) enforce these per field; the services table derives
each topic's and control's largest acceptable payload from them, and the runtime refuses anything
bigger before decoding (rejection reason `too_large`). Change a limit here and both follow.
"""
from __future__ import annotations

from typing import Annotated

from pydantic import StringConstraints

MAX_NAME_CHARS = 128  # robot ids, stages, sources, upload ids; models (the store allows 128)
MAX_HOST_CHARS = 255  # a host name (DNS allows 253)
MAX_TEXT_CHARS = 512  # reasons, errors, free text in health
MAX_STAMPS = 16  # stage stamps in a header (the chain has 4 stages; relays add a few)
MAX_DETAIL_ENTRIES = 256  # health detail counters

# A machine-vision sensor up to WUXGA (1920x1200); each side at most 4096 (a header declaring more is
# refused before its image is decoded).
MAX_IMAGE_SIDE = 4096
MAX_IMAGE_PIXELS = 1920 * 1200
MAX_IMAGE_BYTES = MAX_IMAGE_PIXELS * 3  # bgr8; a JPEG of such an image is smaller

HIT_BYTES = 8  # int16 x (row, col, ray, d)
MAX_HITS = 16384  # the default scan gives hundreds to a few thousand per frame
MAX_HITS_BYTES = MAX_HITS * HIT_BYTES
MARK_BYTES = 6  # int16 x (row, col, mark index)
MAX_MARKS = 1024  # colour marks of one frame (a coarse grid of the frame; the preprocess default sends <= 256)
MAX_MARKS_BYTES = MAX_MARKS * MARK_BYTES

MAX_CHUNK_BYTES = 8 * 2**20  # one model-upload chunk (the client sends 4 MiB by default)
MAX_UPLOAD_FILES = 64

# Everything in a message besides its one bulk field (header with MAX_STAMPS stamps, names, numbers,
# msgpack framing) fits in this, with room to spare.
ENVELOPE_BYTES = 64 * 1024

# What zenoh adds to our payload in one network message (key expression, encoding, timestamp, source info:
# tens of bytes), with room to spare: the margin between the table's largest payload and the largest
# message a session accepts off a link (services_table.MAX_BUS_MESSAGE_BYTES).
ZENOH_FRAMING_MARGIN_BYTES = 64 * 1024

Name = Annotated[str, StringConstraints(max_length=MAX_NAME_CHARS)]
HostName = Annotated[str, StringConstraints(max_length=MAX_HOST_CHARS)]
Text = Annotated[str, StringConstraints(max_length=MAX_TEXT_CHARS)]


def max_payload_bytes(bulk_bytes: int = 0) -> int:
    """The largest acceptable encoded message whose one bulk field holds at most `bulk_bytes`."""
    return ENVELOPE_BYTES + bulk_bytes


def clip_text(text: str) -> str:
    """`text` cut to MAX_TEXT_CHARS, so echoing hostile input never makes our own messages grow."""
    return text if len(text) <= MAX_TEXT_CHARS else text[:MAX_TEXT_CHARS - 3] + "..."

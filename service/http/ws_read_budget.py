"""Reading a WebSocket within its queue budget, before its messages are decoded.

uvicorn's WebSocket protocol decodes every frame of the bytes one read gives it and queues each message for
the app, so a single read of tiny messages (a ``ping`` flood: up to 256 KiB, some 9,000 messages) is all
decoded and queued before the app sees the first. :func:`feed_within_queue` hands the protocol the bytes a
slice at a time and stops once more messages wait than the connection may queue
(``RSMT_WS_MAX_QUEUED_MESSAGES``): reading pauses and the rest is never decoded, and the app closes the
connection with 1008 at its next message (:mod:`service.sessions.message_budget`). uvicorn stops reading
after queueing a message until the app has taken them all, so within one read is the only place such a
queue can grow.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

SLICE_BYTES = 8 << 10


def feed_within_queue(protocol: asyncio.Protocol, data: bytes, limit: int, feed: Callable[[bytes], None]) -> None:
    """Give ``data`` to ``feed`` (the protocol's own ``data_received``) a slice at a time while the protocol's
    message queue holds at most ``limit`` (0: no limit; a protocol without such a queue gets it whole)."""
    queue = getattr(protocol, "queue", None)
    if limit <= 0 or not isinstance(queue, asyncio.Queue):
        feed(data)
        return
    view = memoryview(data)
    for start in range(0, len(data), SLICE_BYTES):
        if queue.qsize() > limit:  # over budget: the app closes the connection; nothing more is decoded
            transport = getattr(protocol, "transport", None)
            if transport is not None:
                transport.pause_reading()
            return
        feed(data if len(data) <= SLICE_BYTES else bytes(view[start:start + SLICE_BYTES]))

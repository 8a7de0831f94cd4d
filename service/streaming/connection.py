"""One WebSocket connection's outgoing side: a bounded, time-ordered send queue, its sender task, the
watchdog (slow client, idle) and closing with the protocol's codes.

Every message leaves through one sender task in due-time order: control messages are due at once,
asap frames when generated, realtime frames on their character's fps clock. Per character at most
``send_queue_frames`` frames wait; at that point the scheduler parks the character, and if it
stays parked for ``slow_client_grace_s`` the connection is closed with 1008.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import logging
import socket
from typing import Any

import orjson
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocket

from service.metrics import Metrics
from service.streaming.stream import Stream

log = logging.getLogger(__name__)

_FRAME, _MESSAGE, _END = 0, 1, 2
CLOSE_NORMAL, CLOSE_GOING_AWAY, CLOSE_POLICY, CLOSE_TOO_BIG, CLOSE_INTERNAL = 1000, 1001, 1008, 1009, 1011
_RAW_SEND = "rsmt.raw_send"


class Connection:
    """The server side of one ``/v1/stream`` connection (outgoing half; the route reads messages)."""

    def __init__(self, ws: WebSocket, encoding: str, *, send_queue_frames: int, slow_client_grace_s: float,
                 idle_timeout_s: float, max_pending_messages: int, metrics: Metrics | None = None) -> None:
        self.ws = ws
        self.encoding = encoding
        self.capacity = send_queue_frames
        self.grace_s = slow_client_grace_s
        self.idle_timeout_s = idle_timeout_s
        self.max_pending = max_pending_messages
        self.metrics = metrics
        self.streams: dict[str, Stream] = {}  # live characters by id
        self.reserved: set[str] = set()  # ids whose start is being prepared
        self.busy = 0  # client messages being handled
        self.owner = ""  # the API key's owner digest (service.caller.Caller): the per-key character share
        self.closing = False
        self.close_code: int | None = None
        self.closed = asyncio.Event()
        self._loop = asyncio.get_running_loop()
        self.last_activity = self._loop.time()
        self._heap: list[tuple[float, int, int, Any, Any]] = []
        self._order = itertools.count()
        self._pending_messages = 0
        self._has_items = asyncio.Event()
        self._sender: asyncio.Task | None = None
        self._watchdog: asyncio.Task | None = None
        self._slots = itertools.count()
        self._auto_ids = itertools.count()

    # ------------------------------------------------------------------ lifecycle
    def start(self, send_buffer_bytes: int = 0) -> None:
        if send_buffer_bytes:
            self._limit_send_buffer(send_buffer_bytes)
        self._sender = self._loop.create_task(self._send_loop(), name="ws-sender")
        self._sender.add_done_callback(_sender_done)
        self._watchdog = self._loop.create_task(self._watch(), name="ws-watchdog")

    def touch(self) -> None:
        """A client message arrived: the idle clock restarts."""
        self.last_activity = self._loop.time()

    def next_slot(self) -> int:
        return next(self._slots)

    def next_character_id(self) -> str:
        while True:
            cid = f"c{next(self._auto_ids)}"
            if cid not in self.streams and cid not in self.reserved:
                return cid

    async def close(self, code: int, reason: str) -> None:
        """Stop every character, discard queued frames and close with ``code`` (idempotent)."""
        if self.closing:
            return
        self.closing = True
        self.close_code = code
        self._drop_all()
        await self._stop_sender()
        if self.metrics is not None:
            self.metrics.closes.labels(str(code)).inc()
        try:
            # The close frame waits behind unsent data; a client that never reads gets aborted.
            async with asyncio.timeout(max(5.0, self.grace_s)):
                await self.ws.close(code=code, reason=reason[:120])
        except TimeoutError:
            self._abort()
        except Exception:  # already disconnected
            pass
        self.closed.set()

    async def shutdown(self) -> None:
        """The client went away: stop every character and the tasks, without a close frame."""
        self.closing = True
        self._drop_all()
        await self._stop_sender()
        if self._watchdog is not None and self._watchdog is not asyncio.current_task():
            self._watchdog.cancel()
        self.closed.set()

    def _drop_all(self) -> None:
        for stream in list(self.streams.values()):
            if stream.scheduler is not None:
                stream.scheduler.drop(stream)
        self.streams.clear()
        self._heap.clear()

    async def _stop_sender(self) -> None:
        task = self._sender
        if task is not None and task is not asyncio.current_task() and not task.done():
            task.cancel()
            try:
                await task
            except (asyncio.CancelledError, Exception):
                pass

    def transport(self) -> Any:
        """uvicorn's transport of this connection, or None under another server."""
        raw = self.ws.scope.get(_RAW_SEND)
        return getattr(getattr(raw, "__self__", None), "transport", None)

    def _limit_send_buffer(self, size: int) -> None:
        # Loopback and LAN sockets autotune their send buffer up to 4 MiB: a client that stops reading
        # would hold that much before the send queue fills. A fixed buffer bounds it.
        transport = self.transport()
        sock = transport.get_extra_info("socket") if transport is not None else None
        if sock is not None:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, size)
            except OSError:
                log.debug("could not set SO_SNDBUF", exc_info=True)

    def _abort(self) -> None:
        transport = self.transport()
        if transport is not None:
            log.warning("closing a WebSocket whose client does not read: connection aborted")
            transport.abort()

    # ------------------------------------------------------------------ queueing (event loop)
    def send_message(self, message: dict) -> None:
        """Queue a control message (JSON text), due now."""
        if self.closing:
            return
        self._pending_messages += 1
        self._push(self._loop.time(), _MESSAGE, None, orjson.dumps(message).decode())
        if self._pending_messages > self.max_pending:
            self._loop.create_task(self.close(CLOSE_POLICY, "client not reading (too many queued messages)"))

    def deliver_frame(self, stream: Stream, seq: int, payload: str | bytes, now: float) -> None:
        if self.closing:
            return
        due = stream.due(seq, now)
        stream.last_due = due
        stream.queued += 1
        self._push(due, _FRAME, stream, payload)
        if stream.queued >= self.capacity and stream.scheduler is not None:
            stream.scheduler.park(stream, now)

    def deliver_end(self, stream: Stream, reason: str) -> None:
        """Queue ``end`` after the character's last frame; it stops counting as live now."""
        self.streams.pop(stream.id, None)
        if self.closing:
            return
        due = stream.last_due if reason == "arrived" else self._loop.time()
        self._push(due, _END, stream, reason)

    def deliver_failure(self, stream: Stream, message: str) -> None:
        self.streams.pop(stream.id, None)
        self.send_message({"type": "error", "code": "internal", "message": message, "character": stream.id})

    def cancel(self, stream: Stream) -> None:
        if stream.scheduler is not None:
            stream.scheduler.drop(stream)
        self.deliver_end(stream, "cancelled")

    def _push(self, due: float, kind: int, stream: Any, payload: Any) -> None:
        heapq.heappush(self._heap, (due, next(self._order), kind, stream, payload))
        self._has_items.set()

    # ------------------------------------------------------------------ the sender task
    async def _send_loop(self) -> None:
        loop = self._loop
        ws = self.ws
        metrics = self.metrics
        heap = self._heap
        while True:
            if not heap:
                self._has_items.clear()
                await self._has_items.wait()
                continue
            now = loop.time()
            due = heap[0][0]
            if due > now + 5e-4:
                self._has_items.clear()
                try:
                    async with asyncio.timeout(due - now):
                        await self._has_items.wait()
                except TimeoutError:
                    pass
                continue
            _, _, kind, stream, payload = heapq.heappop(heap)
            if kind == _FRAME:
                if stream.cancelled:
                    continue
                if isinstance(payload, bytes):
                    await ws.send_bytes(payload)
                else:
                    await ws.send_text(payload)
                stream.queued -= 1
                stream.sent += 1
                if stream.parked and stream.queued <= self.capacity // 2 and stream.scheduler is not None:
                    stream.scheduler.unpark(stream)
                if metrics is not None:
                    metrics.frames_sent.inc()
                    metrics.send_lag_seconds.observe(max(0.0, loop.time() - due))
            elif kind == _END:
                await ws.send_text(orjson.dumps({"type": "end", "character": stream.id, "slot": stream.slot,
                                                 "reason": payload, "frames": stream.sent}).decode())
            else:
                self._pending_messages -= 1
                await ws.send_text(payload)

    # ------------------------------------------------------------------ the watchdog task
    async def _watch(self) -> None:
        interval = min(0.25, self.grace_s / 4, self.idle_timeout_s / 4)
        while not self.closing:
            await asyncio.sleep(interval)
            now = self._loop.time()
            if self._sender is not None and self._sender.done() and not self._sender.cancelled():
                exc = self._sender.exception()
                if exc is not None:  # the client vanished mid-send; the route sees the disconnect
                    log.debug("sender stopped: %r", exc)
                    return
            stalled = [s for s in self.streams.values() if s.parked_at is not None and now - s.parked_at > self.grace_s]
            if stalled:
                await self.close(CLOSE_POLICY, f"client not reading: {len(stalled)} character(s) had a full send "
                                               f"queue for over {self.grace_s:g} s")
                return
            if not self.streams and not self.reserved and not self.busy and not self._heap \
                    and now - self.last_activity > self.idle_timeout_s:
                await self.close(CLOSE_NORMAL, "idle")
                return


def _sender_done(task: asyncio.Task[None]) -> None:
    """Retrieve the sender's exception (a client gone mid-write) so that asyncio never prints it as a
    multi-line 'Task exception was never retrieved' on stderr; the route sees the disconnect itself."""
    if not task.cancelled() and (exc := task.exception()) is not None:
        log.debug("sender stopped: %r", exc)


class RawSendMiddleware:
    """Keeps the server's own ``send`` of each WebSocket in its scope, so a connection whose client stops
    reading can be aborted when even the close frame cannot be written (uvicorn exposes its transport there)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "websocket":
            scope[_RAW_SEND] = send
        await self.app(scope, receive, send)

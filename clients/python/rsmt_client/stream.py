"""WebSocket clients of ``/v1/stream`` (the ``websockets`` library): :class:`StreamClient` and :class:`AsyncStreamClient`.

The server speaks first (``hello``: model, skeleton, binary ``frame_layout``, limits). The client
then sends ``start`` / ``retarget`` / ``style`` / ``cancel`` / ``ping`` and reads ``started``,
``frame``, ``end``, ``retargeted``, ``style_changed``, ``error`` and ``pong``. Frames come back as
:class:`Frame` whichever encoding was chosen. The protocol itself (messages, frame decoding,
per-character reassembly, retry decisions) is :mod:`rsmt_client.stream_protocol`; the two classes
here only connect, send, receive and wait.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any, Self

from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from rsmt_client._retry import Retrying, RetryPolicy
from rsmt_client.errors import RsmtError
from rsmt_client.frames import Frame, FrameLayout, Message
from rsmt_client.http_protocol import DEFAULT_URL
from rsmt_client.motion import Poses
from rsmt_client.stream_protocol import (
    MAX_MESSAGE_BYTES,
    StreamResult,
    StreamSession,
    closed_error,
    handshake_headers,
    refused_handshake,
    stream_url,
)

__all__ = ["AsyncStreamClient", "Frame", "FrameLayout", "StreamClient", "StreamResult", "stream_url"]


def _wait_after_failed_handshake(retrying: Retrying, url: str, exc: Exception) -> float:
    if isinstance(exc, InvalidStatus):
        status, headers, err = refused_handshake(exc)
        return retrying.wait_or_raise(status, headers, err, cause=exc)
    return retrying.wait_or_raise(None, None, RsmtError("connection", f"cannot reach {url}: {exc}"), cause=exc)


class _SessionView:
    """What both clients expose of their :class:`StreamSession`."""

    _session: StreamSession

    @property
    def hello(self) -> Message:
        return self._session.hello

    @property
    def model(self) -> dict[str, Any]:
        return self._session.model

    @property
    def layout(self) -> FrameLayout:
        return self._session.layout

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._session.joint_names


class StreamClient(_SessionView):
    """Synchronous ``/v1/stream`` client (``websockets.sync``); one connection, any number of characters.

    ``StreamClient(url, api_key=..., encoding="binary")`` connects, reads ``hello`` (``.hello``,
    ``.model``, ``.layout``), then: ``start(...)`` returns the character id; ``recv()`` gives the
    next :class:`Frame` or message dict; ``collect(character)`` reads until that character ends.
    A refused handshake (429, 503) is retried with the :class:`RetryPolicy`.
    """

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, encoding: str = "json",
                 retry: RetryPolicy | None = None, open_timeout: float = 30.0, token_in_query: bool = False,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.url = stream_url(url, encoding, api_key if token_in_query else None)
        self.encoding = encoding
        retrying = Retrying(retry or RetryPolicy())
        while True:
            try:
                self._ws = connect(self.url, additional_headers=handshake_headers(api_key, token_in_query),
                                   open_timeout=open_timeout, proxy=None, compression=None, max_size=MAX_MESSAGE_BYTES)
                break
            except (InvalidStatus, OSError) as exc:
                sleep(_wait_after_failed_handshake(retrying, self.url, exc))
        self._session = StreamSession.from_hello(self._ws.recv(open_timeout))

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._ws.close()

    # ------------------------------------------------------------------ sending
    def send(self, message: Message) -> None:
        try:
            self._ws.send(self._session.encode(message))
        except ConnectionClosed as exc:
            raise closed_error(exc) from exc

    def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
              seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
              character: str | None = None, model: str | None = None, request_id: Any = None,
              exact_arrival: bool = False) -> str:
        """Send ``start``; returns the character id (``character`` or a new one). Frames follow ``started``."""
        character = character or StreamSession.new_id()
        self.send(StreamSession.start_message(context, target, frames, style_id, style, seed, deterministic, pace,
                                              character, model, request_id, exact_arrival))
        return character

    def retarget(self, character: str, target: Any = None, frames: int | None = None, request_id: Any = None) -> None:
        self.send(StreamSession.retarget_message(character, target, frames, request_id))

    def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        self.send(StreamSession.style_message(character, style_id, style))

    def cancel(self, character: str) -> None:
        self.send(StreamSession.cancel_message(character))

    def ping(self, ident: Any = None) -> None:
        self.send(StreamSession.ping_message(ident))

    # ------------------------------------------------------------------ receiving
    def recv(self, timeout: float | None = None) -> Frame | Message:
        """The next frame or message (queued ones first); raises ``RsmtError("timeout")`` / ``("closed")``."""
        queued = self._session.next_pending()
        return queued if queued is not None else self._recv_socket(timeout)

    def _recv_socket(self, timeout: float | None) -> Frame | Message:
        try:
            raw = self._ws.recv(timeout)
        except TimeoutError as exc:
            raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
        except ConnectionClosed as exc:
            raise closed_error(exc) from exc
        return self._session.parse(raw)

    def collect(self, character: str, timeout: float = 60.0,
                on_frame: Callable[[StreamClient, Frame], None] | None = None) -> StreamResult:
        """Read until ``character`` ends; other characters' traffic stays queued for later ``recv`` calls.

        An ``error`` about this character (or about none) raises :class:`RsmtError`.
        """
        result, ended = self._session.begin_collect(character)
        deadline = time.monotonic() + timeout
        while not ended:
            left = deadline - time.monotonic()
            if left <= 0:
                raise StreamSession.collect_timeout(character, timeout)
            frames = len(result.frames)
            ended = self._session.take(self._recv_socket(left), result)
            if on_frame is not None and len(result.frames) > frames:
                on_frame(self, result.frames[-1])
        return result

    def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                   seed: int | None = None, deterministic: bool = False, pace: str = "asap",
                   timeout: float = 60.0, exact_arrival: bool = False) -> Poses:
        """A whole transition over the stream (start, then collect): the same frames ``POST /v1/transition`` gives."""
        c = self.start(context, target, frames, style_id, style, seed, deterministic, pace, exact_arrival=exact_arrival)
        return self._session.transition_poses(self.collect(c, timeout))


class AsyncStreamClient(_SessionView):
    """The asyncio twin of :class:`StreamClient`: ``client = await AsyncStreamClient.connect(url)``."""

    def __init__(self, ws: AsyncConnection, session: StreamSession, url: str, encoding: str) -> None:
        self._ws = ws
        self._session = session
        self.url = url
        self.encoding = encoding

    @classmethod
    async def connect(cls, url: str = DEFAULT_URL, api_key: str | None = None, encoding: str = "json",
                      retry: RetryPolicy | None = None, open_timeout: float = 30.0,
                      token_in_query: bool = False, max_queue: int | None = 16) -> AsyncStreamClient:
        """Connect and read ``hello``. ``max_queue``: messages buffered before reading from the socket pauses
        (None: never pause, so a busy reader cannot slow the server down; a load test wants that)."""
        full = stream_url(url, encoding, api_key if token_in_query else None)
        retrying = Retrying(retry or RetryPolicy())
        while True:
            try:
                ws = await async_connect(full, additional_headers=handshake_headers(api_key, token_in_query),
                                         open_timeout=open_timeout, proxy=None, compression=None,
                                         max_size=MAX_MESSAGE_BYTES, max_queue=max_queue)
                break
            except (InvalidStatus, OSError) as exc:
                await asyncio.sleep(_wait_after_failed_handshake(retrying, full, exc))
        return cls(ws, StreamSession.from_hello(await asyncio.wait_for(ws.recv(), open_timeout)), full, encoding)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self._ws.close()

    async def send(self, message: Message) -> None:
        try:
            await self._ws.send(self._session.encode(message))
        except ConnectionClosed as exc:
            raise closed_error(exc) from exc

    async def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                    seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
                    character: str | None = None, model: str | None = None, request_id: Any = None,
                    exact_arrival: bool = False) -> str:
        character = character or StreamSession.new_id()
        await self.send(StreamSession.start_message(context, target, frames, style_id, style, seed, deterministic, pace,
                                                    character, model, request_id, exact_arrival))
        return character

    async def retarget(self, character: str, target: Any = None, frames: int | None = None,
                       request_id: Any = None) -> None:
        await self.send(StreamSession.retarget_message(character, target, frames, request_id))

    async def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        await self.send(StreamSession.style_message(character, style_id, style))

    async def cancel(self, character: str) -> None:
        await self.send(StreamSession.cancel_message(character))

    async def ping(self, ident: Any = None) -> None:
        await self.send(StreamSession.ping_message(ident))

    async def recv(self, timeout: float | None = None) -> Frame | Message:
        queued = self._session.next_pending()
        return queued if queued is not None else await self._recv_socket(timeout)

    async def _recv_socket(self, timeout: float | None) -> Frame | Message:
        try:
            raw = await asyncio.wait_for(self._ws.recv(), timeout)
        except TimeoutError as exc:
            raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
        except ConnectionClosed as exc:
            raise closed_error(exc) from exc
        return self._session.parse(raw)

    async def collect(self, character: str, timeout: float = 60.0) -> StreamResult:
        result, ended = self._session.begin_collect(character)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while not ended:
            left = deadline - loop.time()
            if left <= 0:
                raise StreamSession.collect_timeout(character, timeout)
            ended = self._session.take(await self._recv_socket(left), result)
        return result

    async def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None,
                         style: Any = None, seed: int | None = None, deterministic: bool = False, pace: str = "asap",
                         timeout: float = 60.0, exact_arrival: bool = False) -> Poses:
        c = await self.start(context, target, frames, style_id, style, seed, deterministic, pace,
                             exact_arrival=exact_arrival)
        return self._session.transition_poses(await self.collect(c, timeout))

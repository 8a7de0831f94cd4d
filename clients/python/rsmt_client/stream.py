"""WebSocket clients of ``/v1/stream`` (the ``websockets`` library): :class:`StreamClient` and :class:`AsyncStreamClient`.

The server speaks first (``hello``: model, skeleton, binary ``frame_layout``, limits). The client
then sends ``start`` / ``retarget`` / ``style`` / ``cancel`` / ``ping`` and reads ``started``,
``frame``, ``end``, ``retargeted``, ``style_changed``, ``error`` and ``pong``. Frames come back as
:class:`Frame` whichever encoding was chosen. The protocol itself (messages, frame decoding,
per-character reassembly, retry decisions) is :mod:`rsmt_client.stream_protocol`; the two classes
here only connect, send, receive and wait.

With ``failover=True`` a lost connection (its replica died, restarted or drained) is opened again through
the same URL and every live character resumes from the last frames it received
(:mod:`rsmt_client.stream_failover`): the caller sees a stall, then the frames that were still to come,
numbered on. Styles registered through :meth:`StreamClient.register_style` (or ``register_style_clips``) are
registered again when a server answers ``unknown_style``.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Sequence
from typing import Any, Self

from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from rsmt_client._retry import Retrying, RetryPolicy
from rsmt_client.errors import RsmtError
from rsmt_client.frames import Frame, FrameLayout, Message
from rsmt_client.http import AsyncClient, Client
from rsmt_client.http_protocol import DEFAULT_URL, default_style_name
from rsmt_client.motion import Poses
from rsmt_client.motion_cuts import Cutter, ModelLimits
from rsmt_client.stream_failover import NO_RESUME_CLOSE_CODES, Actions, Failover, http_url, style_body
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
    """What both clients expose of their :class:`StreamSession`, and the failover decisions they share."""

    _session: StreamSession
    _failover: Failover | None
    _closing: bool
    _cuts: Cutter | None = None

    @property
    def resumes(self) -> int:
        """Reconnections that resumed characters (``failover=True``)."""
        return 0 if self._failover is None else self._failover.resumes

    def _new_failover(self, enabled: bool) -> Failover | None:
        if not enabled:
            return None
        return Failover(int(self._session.model["context_frames"]), self._session.fps, self._session.joint_names)

    def _can_resume(self, exc: ConnectionClosed) -> bool:
        code = getattr(exc.rcvd, "code", None)
        return (self._failover is not None and self._failover.live and not self._closing
                and code not in NO_RESUME_CLOSE_CODES)

    def _fit(self, message: Message) -> Message:
        """``message`` cut to what the model reads (a whole take works as context, target or style)."""
        if self._cuts is None:  # one per client, so a cut style clip is reported once
            self._cuts = Cutter(ModelLimits.of(self._session.model))
        return self._session.fitted(message, self._cuts)

    def _too_large_style(self, message: Message) -> bool:
        """A message whose inline style clip makes it larger than a WebSocket message may be: the clip is
        registered over HTTP instead and the message names it by id."""
        return isinstance(message.get("style"), dict) and not self._session.fits(message)

    @staticmethod
    def _by_id(message: Message, style_id: str) -> Message:
        out = {k: v for k, v in message.items() if k != "style"}
        out["style_id"] = style_id
        return out

    def _sending(self, message: Message) -> str:
        text = self._session.encode(message)
        if self._failover is not None:
            self._failover.sent(message)
        return text

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
                 sleep: Callable[[float], None] = time.sleep, failover: bool = False) -> None:
        self.url = stream_url(url, encoding, api_key if token_in_query else None)
        self.encoding = encoding
        self._api_key, self._token_in_query, self._open_timeout = api_key, token_in_query, open_timeout
        self._retry, self._sleep, self._closing = retry or RetryPolicy(), sleep, False
        self._http: Client | None = None
        self._ws, self._session = self._open()
        self._failover = self._new_failover(failover)

    def _open(self) -> tuple[ClientConnection, StreamSession]:
        """Connect (retrying refused handshakes with the policy) and read ``hello``."""
        retrying = Retrying(self._retry)
        while True:
            try:
                ws = connect(self.url, additional_headers=handshake_headers(self._api_key, self._token_in_query),
                             open_timeout=self._open_timeout, proxy=None, compression=None, max_size=MAX_MESSAGE_BYTES)
                return ws, StreamSession.from_hello(ws.recv(self._open_timeout))
            except (InvalidStatus, OSError, ConnectionClosed) as exc:
                self._sleep(_wait_after_failed_handshake(retrying, self.url, exc))

    def _resume(self) -> None:
        """A new connection through the same URL, the queued traffic kept, every live character started again."""
        assert self._failover is not None
        for attempt in range(self._retry.attempts):
            pending = self._session.pending
            self._ws, self._session = self._open()
            self._session.pending.extend(pending)
            try:
                for message in self._failover.resume_messages():
                    self._ws.send(self._session.encode(message))
                return
            except ConnectionClosed as exc:
                if not self._can_resume(exc) or attempt + 1 == self._retry.attempts:
                    raise closed_error(exc) from exc

    def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> str:
        """``POST /v1/styles`` on the same server; returns the id. With ``failover`` the clip is kept and
        registered again wherever a stream meets ``unknown_style`` for it."""
        return self._register(style_body([motion], name, model))

    def register_style_clips(self, motions: Sequence[Any], name: str | None = None, model: str | None = None) -> str:
        """``POST /v1/styles`` with 1 to 5 clips of one style encoded together (as
        :meth:`rsmt_client.Client.register_style_clips`); returns the id. With ``failover`` the clips are kept
        and registered again, together, wherever a stream meets ``unknown_style`` for it."""
        return self._register(style_body(motions, name, model))

    def _register(self, body: dict[str, Any]) -> str:
        http = self._http_client()
        info = (http.register_style_clips(body["motions"], body["name"], body.get("model")) if "motions" in body
                else http.register_style(body["motion"], body["name"], body.get("model")))
        if self._failover is not None:
            self._failover.remember_style(str(info["style_id"]), body)
        return str(info["style_id"])

    def _http_client(self) -> Client:
        if self._http is None:
            self._http = Client(http_url(self.url), api_key=self._api_key, retry=self._retry, sleep=self._sleep)
        return self._http

    def _act(self, actions: Actions) -> Frame | Message | None:
        if actions.register is not None:
            self._register(actions.register[1])
        for message in actions.send:  # the message that named the style, once more (not recorded again)
            try:
                self._ws.send(self._session.encode(message))
            except ConnectionClosed:
                pass  # the next receive resumes
        return actions.item

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._closing = True
        self._ws.close()
        if self._http is not None:
            self._http.close()

    # ------------------------------------------------------------------ sending
    def send(self, message: Message) -> None:
        text = self._sending(message)
        try:
            self._ws.send(text)
        except ConnectionClosed as exc:
            if not self._can_resume(exc):
                raise closed_error(exc) from exc
            self._resume()  # the resumed starts carry what this message said

    def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
              seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
              character: str | None = None, model: str | None = None, request_id: Any = None,
              exact_arrival: bool | None = None, style_strength: float | None = None) -> str:
        """Send ``start``; returns the character id (``character`` or a new one). Frames follow ``started``.
        ``target``: a Motion, or a :class:`rsmt_client.placement.TargetAt` place and facing."""
        character = character or StreamSession.new_id()
        message = self._fit(StreamSession.start_message(context, target, frames, style_id, style, seed, deterministic,
                                                        pace, character, model, request_id, exact_arrival,
                                                        style_strength))
        self.send(self._inline_or_registered(message, style))
        return character

    def _inline_or_registered(self, message: Message, style: Any) -> Message:
        if not self._too_large_style(message):
            return message
        return self._by_id(message, self.register_style(message["style"], default_style_name(style), message.get("model")))

    def retarget(self, character: str, target: Any = None, frames: int | None = None, request_id: Any = None) -> None:
        self.send(self._fit(StreamSession.retarget_message(character, target, frames, request_id)))

    def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        self.send(self._inline_or_registered(self._fit(StreamSession.style_message(character, style_id, style)), style))

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
        while True:
            try:
                raw = self._ws.recv(timeout)
            except TimeoutError as exc:
                raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
            except ConnectionClosed as exc:
                if not self._can_resume(exc):
                    raise closed_error(exc) from exc
                self._resume()
                continue
            item = self._session.parse(raw)
            if self._failover is None:
                return item
            out = self._act(self._failover.received(item))
            if out is not None:
                return out

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
                   timeout: float = 60.0, exact_arrival: bool | None = None, style_strength: float | None = None) -> Poses:
        """A whole transition over the stream (start, then collect): the same frames ``POST /v1/transition`` gives."""
        c = self.start(context, target, frames, style_id, style, seed, deterministic, pace, exact_arrival=exact_arrival,
                       style_strength=style_strength)
        return self._session.transition_poses(self.collect(c, timeout))


class AsyncStreamClient(_SessionView):
    """The asyncio twin of :class:`StreamClient`: ``client = await AsyncStreamClient.connect(url)``."""

    def __init__(self, ws: AsyncConnection, session: StreamSession, url: str, encoding: str,
                 reconnect: Callable[[], Awaitable[tuple[AsyncConnection, StreamSession]]] | None = None,
                 api_key: str | None = None, retry: RetryPolicy | None = None, failover: bool = False) -> None:
        self._ws = ws
        self._session = session
        self.url = url
        self.encoding = encoding
        self._reconnect, self._api_key, self._retry = reconnect, api_key, retry or RetryPolicy()
        self._closing = False
        self._http: AsyncClient | None = None
        self._failover = self._new_failover(failover and reconnect is not None)

    @classmethod
    async def connect(cls, url: str = DEFAULT_URL, api_key: str | None = None, encoding: str = "json",
                      retry: RetryPolicy | None = None, open_timeout: float = 30.0,
                      token_in_query: bool = False, max_queue: int | None = 16,
                      failover: bool = False) -> AsyncStreamClient:
        """Connect and read ``hello``. ``max_queue``: messages buffered before reading from the socket pauses
        (None: never pause, so a busy reader cannot slow the server down; a load test wants that).
        ``failover``: resume live characters on a new connection when this one is lost (module doc)."""
        full = stream_url(url, encoding, api_key if token_in_query else None)
        policy = retry or RetryPolicy()

        async def open_() -> tuple[AsyncConnection, StreamSession]:
            retrying = Retrying(policy)
            while True:
                try:
                    ws = await async_connect(full, additional_headers=handshake_headers(api_key, token_in_query),
                                             open_timeout=open_timeout, proxy=None, compression=None,
                                             max_size=MAX_MESSAGE_BYTES, max_queue=max_queue)
                    return ws, StreamSession.from_hello(await asyncio.wait_for(ws.recv(), open_timeout))
                except (InvalidStatus, OSError, ConnectionClosed) as exc:
                    await asyncio.sleep(_wait_after_failed_handshake(retrying, full, exc))

        ws, session = await open_()
        return cls(ws, session, full, encoding, open_, api_key, policy, failover)

    async def _resume(self) -> None:
        assert self._failover is not None and self._reconnect is not None
        for attempt in range(self._retry.attempts):
            pending = self._session.pending
            self._ws, self._session = await self._reconnect()
            self._session.pending.extend(pending)
            try:
                for message in self._failover.resume_messages():
                    await self._ws.send(self._session.encode(message))
                return
            except ConnectionClosed as exc:
                if not self._can_resume(exc) or attempt + 1 == self._retry.attempts:
                    raise closed_error(exc) from exc

    async def register_style(self, motion: Any, name: str | None = None, model: str | None = None) -> str:
        """As :meth:`StreamClient.register_style`."""
        return await self._register(style_body([motion], name, model))

    async def register_style_clips(self, motions: Sequence[Any], name: str | None = None,
                                   model: str | None = None) -> str:
        """As :meth:`StreamClient.register_style_clips`."""
        return await self._register(style_body(motions, name, model))

    async def _register(self, body: dict[str, Any]) -> str:
        http = self._http_client()
        info = await (http.register_style_clips(body["motions"], body["name"], body.get("model")) if "motions" in body
                      else http.register_style(body["motion"], body["name"], body.get("model")))
        if self._failover is not None:
            self._failover.remember_style(str(info["style_id"]), body)
        return str(info["style_id"])

    def _http_client(self) -> AsyncClient:
        if self._http is None:
            self._http = AsyncClient(http_url(self.url), api_key=self._api_key, retry=self._retry)
        return self._http

    async def _act(self, actions: Actions) -> Frame | Message | None:
        if actions.register is not None:
            await self._register(actions.register[1])
        for message in actions.send:
            try:
                await self._ws.send(self._session.encode(message))
            except ConnectionClosed:
                pass  # the next receive resumes
        return actions.item

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        self._closing = True
        await self._ws.close()
        if self._http is not None:
            await self._http.aclose()

    async def send(self, message: Message) -> None:
        text = self._sending(message)
        try:
            await self._ws.send(text)
        except ConnectionClosed as exc:
            if not self._can_resume(exc):
                raise closed_error(exc) from exc
            await self._resume()

    async def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                    seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
                    character: str | None = None, model: str | None = None, request_id: Any = None,
                    exact_arrival: bool | None = None, style_strength: float | None = None) -> str:
        character = character or StreamSession.new_id()
        message = self._fit(StreamSession.start_message(context, target, frames, style_id, style, seed, deterministic,
                                                        pace, character, model, request_id, exact_arrival,
                                                        style_strength))
        await self.send(await self._inline_or_registered(message, style))
        return character

    async def _inline_or_registered(self, message: Message, style: Any) -> Message:
        if not self._too_large_style(message):
            return message
        style_id = await self.register_style(message["style"], default_style_name(style), message.get("model"))
        return self._by_id(message, style_id)

    async def retarget(self, character: str, target: Any = None, frames: int | None = None,
                       request_id: Any = None) -> None:
        await self.send(self._fit(StreamSession.retarget_message(character, target, frames, request_id)))

    async def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        message = self._fit(StreamSession.style_message(character, style_id, style))
        await self.send(await self._inline_or_registered(message, style))

    async def cancel(self, character: str) -> None:
        await self.send(StreamSession.cancel_message(character))

    async def ping(self, ident: Any = None) -> None:
        await self.send(StreamSession.ping_message(ident))

    async def recv(self, timeout: float | None = None) -> Frame | Message:
        queued = self._session.next_pending()
        return queued if queued is not None else await self._recv_socket(timeout)

    async def _recv_socket(self, timeout: float | None) -> Frame | Message:
        while True:
            try:
                raw = await asyncio.wait_for(self._ws.recv(), timeout)
            except TimeoutError as exc:
                raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
            except ConnectionClosed as exc:
                if not self._can_resume(exc):
                    raise closed_error(exc) from exc
                await self._resume()
                continue
            item = self._session.parse(raw)
            if self._failover is None:
                return item
            out = await self._act(self._failover.received(item))
            if out is not None:
                return out

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
                         timeout: float = 60.0, exact_arrival: bool | None = None,
                         style_strength: float | None = None) -> Poses:
        c = await self.start(context, target, frames, style_id, style, seed, deterministic, pace,
                             exact_arrival=exact_arrival, style_strength=style_strength)
        return self._session.transition_poses(await self.collect(c, timeout))

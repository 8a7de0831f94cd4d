"""Connection guard: read timeouts and a per-address connection cap for uvicorn's httptools protocol.

Uvicorn bounds the idle time between two requests of a keep-alive connection (``timeout_keep_alive``) but
nothing else a client controls: a connection that sends part of its request headers, or a ``Content-Length``
and part of the body, and then stalls is held open for as long as the client likes, and one address may open
as many connections as the file-descriptor limit allows. :class:`GuardedHttpToolsProtocol` is uvicorn's
:class:`~uvicorn.protocols.http.httptools_impl.HttpToolsProtocol` with these bounds added
(:class:`ConnectionLimits`, from the ``RSMT_*`` settings of the app it serves):

* **headers** (``header_timeout_s``): a request's headers must be complete this long after its first byte,
  or after the connection opened for a connection's first request (a connection that sends nothing counts
  too). Past it the connection gets ``408`` (when part of a request arrived) and is closed.
* **body** (``body_timeout_s``): the whole body must have arrived this long after the end of the headers,
  a total and not a gap between chunks, so that a body dripped one byte at a time is bounded as well. Past
  it the connection is closed (``408`` first if the app has not answered yet). The clock runs whether or
  not the app has read the body yet; the service's routes read it at once.
* **WebSocket handshake** (``ws_handshake_timeout_s``): a request carrying ``Upgrade`` must have been
  answered -- the socket open (``101``) or refused -- this long after its first byte. Before the headers
  are complete this tightens the header bound as soon as the ``Upgrade`` header is seen; after them it
  bounds the service's own answer. Once the socket is open the stream's idle timeout (``RSMT_IDLE_TIMEOUT_S``,
  no message and no live character) and uvicorn's pings bound a silent client; a bound on the first
  message would contradict the protocol's idle timeout, which lets a client open a stream before it has
  characters to start.
* **connections per address** (``max_connections_per_address``): open connections (HTTP and WebSocket)
  per peer address as the socket sees it, IPv6 grouped by /64; one past the cap is closed at once, before
  anything is read. Behind a proxy every client shares the proxy's address: the trusted proxies
  (``RSMT_FORWARDED_ALLOW_IPS``) are not capped, and must enforce their own per-client limits.
* **head size** (``max_header_bytes``, ``max_header_line_bytes``): a request line and headers past either
  bound are answered ``431`` and nothing more of the connection is read (:mod:`service.http.header_cap`).
  A chunked body's trailers count with the head and get ``header_timeout_s`` from their first byte (``431``
  / ``408``, or a close when the request was already answered).
* **pipelining** (``pipelined_requests_per_s``): a request sent before the previous answer is started at
  most this often per connection, and nothing more is parsed while one waits: a client that pipelines and
  never reads holds neither a core nor memory. A WebSocket decodes no more once ``ws_max_queued_messages``
  wait (:mod:`service.http.ws_read_budget`).
* **writes** (``write_timeout_s``): a client that stops reading its answers (e.g. pipelines requests and
  never reads) is cut off once the server's writes have been blocked on it this long.

``rsmt serve`` passes this class to uvicorn; under plain uvicorn pass
``--http service.http.connection_guard:GuardedHttpToolsProtocol``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import struct
import weakref
from collections import deque
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any, cast

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from service.http.addresses import address_key
from service.http.header_cap import HEADERS_TOO_LARGE_RESPONSE, BodyMeter, HeadMeter, body_meter
from service.http.ws_read_budget import feed_within_queue
from service.ratelimit import TokenBucket

if TYPE_CHECKING:
    from uvicorn.config import Config
    from uvicorn.server import ServerState

log = logging.getLogger(__name__)
IPNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network

#: A plain-text answer, like uvicorn's own ``400 Invalid HTTP request received.``: the request never
#: reached the app, so it is not in the app's error envelope.
_TIMEOUT_TEXT = b"request not received in time"
REQUEST_TIMEOUT_RESPONSE = (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: text/plain; charset=utf-8\r\n"
                            b"content-length: " + str(len(_TIMEOUT_TEXT)).encode() + b"\r\nconnection: close\r\n\r\n"
                            + _TIMEOUT_TEXT)
#: After writing a 408, a client that does not read it is cut off this long later.
_ABORT_AFTER_S = 1.0


@dataclass(frozen=True)
class ConnectionLimits:
    """The guard's bounds (seconds; ``max_connections_per_address`` 0 turns the cap off)."""

    header_timeout_s: float = 10.0
    body_timeout_s: float = 30.0
    ws_handshake_timeout_s: float = 10.0
    max_connections_per_address: int = 256
    max_header_bytes: int = 32 << 10
    max_header_line_bytes: int = 8 << 10
    write_timeout_s: float = 30.0
    pipelined_requests_per_s: float = 100.0
    ws_max_queued_messages: int = 0
    #: Peers the cap leaves alone: the trusted proxies (``forwarded_allow_ips``: addresses, networks or ``*``),
    #: whose connections carry many clients and which must enforce their own per-client limits.
    uncapped: tuple[str, ...] = ()

    @cached_property
    def _uncapped_networks(self) -> tuple[bool, tuple[IPNetwork, ...], frozenset[str]]:
        networks: list[IPNetwork] = []
        literals: set[str] = set()
        for entry in self.uncapped:
            try:
                networks.append(ipaddress.ip_network(entry, strict=False))
            except ValueError:
                literals.add(entry)
        return "*" in literals, tuple(networks), frozenset(literals)

    def capped(self, host: str) -> bool:
        """Whether connections from ``host`` count under the per-address cap."""
        if not self.max_connections_per_address:
            return False
        if not self.uncapped:
            return True
        everyone, networks, literals = self._uncapped_networks
        if everyone or host in literals:
            return False
        try:
            address = ipaddress.ip_address(host.split("%", 1)[0])
        except ValueError:
            return True
        return not any(address in network for network in networks)

    @classmethod
    def from_app(cls, app: object) -> ConnectionLimits:
        """The limits of the service's settings, found through uvicorn's middleware wrappers (each keeps the
        app it wraps as ``.app``); the defaults for an app that is not the service."""
        for _ in range(16):
            settings = getattr(getattr(getattr(app, "state", None), "service", None), "settings", None)
            if settings is not None:
                return cls(header_timeout_s=settings.header_timeout_s, body_timeout_s=settings.body_timeout_s,
                           ws_handshake_timeout_s=settings.ws_handshake_timeout_s,
                           max_connections_per_address=settings.max_connections_per_address,
                           max_header_bytes=settings.max_header_bytes,
                           max_header_line_bytes=settings.max_header_line_bytes,
                           write_timeout_s=settings.write_timeout_s,
                           pipelined_requests_per_s=settings.pipelined_requests_per_s,
                           ws_max_queued_messages=settings.ws_max_queued_messages,
                           uncapped=tuple(settings.forwarded_allow_ips))
            app = getattr(app, "app", None)
            if app is None:
                break
        return cls()


_limits_of_config: weakref.WeakKeyDictionary[Config, ConnectionLimits] = weakref.WeakKeyDictionary()
_open_per_server: weakref.WeakKeyDictionary[ServerState, dict[str, int]] = weakref.WeakKeyDictionary()


def limits_for(config: Config) -> ConnectionLimits:
    limits = _limits_of_config.get(config)
    if limits is None:
        limits = _limits_of_config[config] = ConnectionLimits.from_app(config.loaded_app)
    return limits


def open_connections(server_state: ServerState) -> dict[str, int]:
    """Open connections per address key of one uvicorn server (a view for tests and diagnostics)."""
    counts = _open_per_server.get(server_state)
    if counts is None:
        counts = _open_per_server[server_state] = {}
    return counts


def _release(server_state: ServerState, key: str | None) -> None:
    if key is None:
        return
    counts = open_connections(server_state)
    left = counts.get(key, 0) - 1
    if left > 0:
        counts[key] = left
    else:
        counts.pop(key, None)


def _close(transport: asyncio.BaseTransport, loop: asyncio.AbstractEventLoop, answer: bool) -> None:
    """Close a connection that ran out of time, with a 408 first if ``answer``; a client that does not read
    even that is cut off shortly after. (uvloop's transports are no ``asyncio.Transport`` subclasses: hence
    the cast rather than an isinstance check.)"""
    stream = cast(asyncio.Transport, transport)
    if stream.is_closing():
        return
    if answer:
        stream.write(REQUEST_TIMEOUT_RESPONSE)
    stream.close()
    if stream.get_write_buffer_size():
        loop.call_later(_ABORT_AFTER_S, stream.abort)


def _reset(transport: asyncio.BaseTransport) -> None:
    """Drop a connection at once with a reset, discarding what the kernel still holds for the peer (a plain
    close would leave it there, in FIN-WAIT, for as long as the peer does not read)."""
    sock = transport.get_extra_info("socket")
    if sock is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        except OSError:
            pass
    cast(asyncio.Transport, transport).abort()


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with header, body and WebSocket-handshake read timeouts and a cap on
    open connections per client address (see the module's docstring)."""

    def __init__(self, config: Config, server_state: ServerState, app_state: dict[str, Any],
                 _loop: asyncio.AbstractEventLoop | None = None) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.limits = limits_for(config)
        if self.ws_protocol_class is not None:
            self.ws_protocol_class = guarded_ws_protocol(self.ws_protocol_class)
        self._address: str | None = None  # the cap's key while this protocol holds a place under it
        self._refused = False
        self._timer: asyncio.TimerHandle | None = None
        self._timer_deadline = 0.0
        self._request_start = 0.0  # loop time of the current request's first byte (or of the connection)
        self._request_bytes = False  # part of a request has arrived (a timeout answers 408)
        self._in_body = False
        self.handshake_deadline: float | None = None  # read by the WebSocket protocol this connection becomes
        self._head = HeadMeter(self.limits.max_header_bytes, self.limits.max_header_line_bytes)
        self._head_refused = False
        self._body: BodyMeter | None = None  # the current request's body framing, once its head is complete
        self._trailer_clock = False  # the trailers' header clock is running
        self._held: deque[tuple[bytes, int]] = deque()  # bytes not parsed yet (from where): behind a pipelined request
        self._pipelined = TokenBucket(self.limits.pipelined_requests_per_s)
        self._pipeline_timer: asyncio.TimerHandle | None = None
        self._write_timer: asyncio.TimerHandle | None = None
        self._cycles: weakref.WeakSet[Any] = weakref.WeakSet()  # this connection's requests (for the write timeout)

    # ------------------------------------------------------------------ connection
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        peer = transport.get_extra_info("peername")
        if isinstance(peer, tuple) and peer and isinstance(peer[0], str) and self.limits.capped(peer[0]):
            key = address_key(peer[0])
            counts = open_connections(self.server_state)
            if counts.get(key, 0) >= self.limits.max_connections_per_address:
                self._refused = True
                transport.abort()  # at once, before anything is read or any state is made for it
                return
            counts[key] = counts.get(key, 0) + 1
            self._address = key
        super().connection_made(transport)
        self._request_start = self.loop.time()
        self._arm(self._request_start + self.limits.header_timeout_s)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._refused:
            return
        self._disarm()
        self._writable()
        self._held.clear()
        if self._pipeline_timer is not None:
            self._pipeline_timer.cancel()
            self._pipeline_timer = None
        _release(self.server_state, self._address)
        self._address = None
        super().connection_lost(exc)

    def handle_websocket_upgrade(self) -> None:
        self._disarm()
        self.handshake_deadline = self._request_start + self.limits.ws_handshake_timeout_s
        super().handle_websocket_upgrade()
        self._address = None  # the WebSocket protocol holds the place from here and releases it when it ends

    def data_received(self, data: bytes) -> None:
        if self._head_refused:
            return
        self._held.append((data, 0))
        if len(self._held) == 1:
            self._feed_held()
        else:  # behind bytes still held: parsed in order after them
            self.flow.pause_reading()

    def _feed_held(self) -> None:
        """Parse the bytes received and not parsed yet, until a pipelined request waits (reading pauses)."""
        held = self._held
        while held:
            data, pos = held[0]
            stop = self._parse(data, pos)
            if self._head_refused or self.transport.is_closing() or self.transport.get_protocol() is not self:
                held.clear()
                return
            if stop < len(data):
                held[0] = (data, stop)
                self.flow.pause_reading()
                return
            held.popleft()

    def _parse(self, data: bytes, pos: int) -> int:
        """Measure and parse ``data[pos:]`` one part at a time (a head, a body with its trailers), so that the
        parser's callbacks at each part's end set how the next is measured; stop while a pipelined request
        waits, at a bound or when the connection changed hands. Returns where it stopped."""
        view = memoryview(data)
        size = len(data)
        while pos < size and not self.pipeline:
            body = self._body
            over, end = self._head.measure(data, pos) if body is None else body.measure(data, pos)
            if over:
                self._refuse_head() if body is None else self._refuse_trailers()
                return pos
            if body is not None and body.in_trailer and not self._trailer_clock:
                self._trailer_clock = True
                self._arm(min(self._timer_deadline, self.loop.time() + self.limits.header_timeout_s))
            stop = size if end < 0 else end
            super().data_received(view[pos:stop])  # type: ignore[arg-type]  # the parser takes any buffer
            pos = stop
            if end >= 0 and body is not None:
                self._body = None  # the body's end as this meter sees it: what follows is measured as a head
            if self._head_refused or self.transport.is_closing() or self.transport.get_protocol() is not self:
                return size
        return pos

    def _refuse_head(self) -> None:
        """431, then no more reading: the connection is closed once the answer had time to leave."""
        self._head_refused = True
        self._disarm()
        log.debug("refusing %s: request head over %d bytes in all or %d in one line", self.client,
                 self.limits.max_header_bytes, self.limits.max_header_line_bytes)
        transport = self.transport
        transport.pause_reading()
        transport.write(HEADERS_TOO_LARGE_RESPONSE)
        self.loop.call_later(_ABORT_AFTER_S, transport.abort)

    def _refuse_trailers(self) -> None:
        """Trailers past a bound: 431 if the request has no answer yet, else a close; nothing more is read."""
        self._head_refused = True
        self._disarm()
        cycle = self.cycle
        answer = cycle is not None and not cycle.response_started
        if cycle is not None:
            cycle.disconnected = True  # the app's receive ends and its sends are dropped
            cycle.message_event.set()
        self.transport.pause_reading()
        if answer:
            self.transport.write(HEADERS_TOO_LARGE_RESPONSE)
        _close(self.transport, self.loop, answer=False)

    # ------------------------------------------------------------------ pipelining
    def on_response_complete(self) -> None:
        if self.pipeline and not self.transport.is_closing() and (wait := self._pipelined.take(self.loop.time())) > 0:
            self.server_state.total_requests += 1
            self._unset_keepalive_if_required()
            self._pipeline_timer = self.loop.call_later(wait, self._start_pipelined)
            return
        super().on_response_complete()
        self._feed_held()

    def _start_pipelined(self) -> None:
        self._pipeline_timer = None
        if self.transport.is_closing() or not self.pipeline:
            return
        self.flow.resume_reading()
        cycle, app = self.pipeline.pop()
        self._start_asgi_task(cycle, app)
        self._feed_held()

    # ------------------------------------------------------------------ write timeout
    def pause_writing(self) -> None:
        super().pause_writing()
        if self._write_timer is None and self.limits.write_timeout_s > 0:
            self._write_timer = self.loop.call_later(self.limits.write_timeout_s, self._write_timed_out)

    def resume_writing(self) -> None:
        super().resume_writing()
        self._writable()

    def _writable(self) -> None:
        if self._write_timer is not None:
            self._write_timer.cancel()
            self._write_timer = None

    def _write_timed_out(self) -> None:
        self._write_timer = None
        log.debug("closing %s: it read none of the answers for %.3g s", self.client, self.limits.write_timeout_s)
        # Every unfinished request of the connection (pipelined ones too: uvicorn's ``cycle`` is only the
        # newest) is marked gone, so that its send returns quietly rather than write to a closed transport.
        for cycle in list(self._cycles):
            if not cycle.response_complete:
                cycle.disconnected = True
        _reset(self.transport)

    # ------------------------------------------------------------------ parser callbacks
    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._request_bytes = True
        if self._timer is None:  # a later request of a keep-alive connection: its own header clock
            self._request_start = self.loop.time()
            self._arm(self._request_start + self.limits.header_timeout_s)

    def on_header(self, name: bytes, value: bytes) -> None:
        super().on_header(name, value)
        if name.lower() == b"upgrade":
            self._arm(min(self._timer_deadline, self._request_start + self.limits.ws_handshake_timeout_s))

    def on_headers_complete(self) -> None:
        self._disarm()
        self._head.reset()
        super().on_headers_complete()
        if self.cycle is not None:
            self._cycles.add(self.cycle)
        if not (self.parser.should_upgrade() and self._should_upgrade()):
            self._in_body = True
            self._body = body_meter(self.headers, self._head)
            self._trailer_clock = False
            self._arm(self.loop.time() + self.limits.body_timeout_s)

    def on_message_complete(self) -> None:
        self._in_body = False
        self._body = None
        self._request_bytes = False
        self._disarm()
        super().on_message_complete()

    # ------------------------------------------------------------------ timer
    def _arm(self, deadline: float) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer_deadline = deadline
        self._timer = self.loop.call_at(deadline, self._timed_out)

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _timed_out(self) -> None:
        self._timer = None
        if self._in_body:
            answer = self.cycle is not None and not self.cycle.response_started
            log.debug("closing %s: request body not received within %.3g s", self.client, self.limits.body_timeout_s)
        else:
            answer = self._request_bytes
            log.debug("closing %s: request headers not received in time", self.client)
        _close(self.transport, self.loop, answer)


class _WebSocketGuard(asyncio.Protocol):
    """Mixed into uvicorn's WebSocket protocol class: keeps the connection's place under the per-address cap
    until it ends, and closes it if the handshake is not answered by the deadline its HTTP protocol set."""

    _guard_server_state: ServerState | None = None
    _guard_address: str | None = None
    _guard_timer: asyncio.TimerHandle | None = None
    _guard_queue_limit = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        upgraded_from = transport.get_protocol()  # still the HTTP protocol while it hands the connection over
        if isinstance(upgraded_from, GuardedHttpToolsProtocol):
            self._guard_queue_limit = upgraded_from.limits.ws_max_queued_messages
            self._guard_server_state = upgraded_from.server_state
            self._guard_address = upgraded_from._address
            if upgraded_from.handshake_deadline is not None:
                self._guard_timer = upgraded_from.loop.call_at(
                    upgraded_from.handshake_deadline, self._handshake_timed_out, transport, upgraded_from.loop)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._guard_timer is not None:
            self._guard_timer.cancel()
            self._guard_timer = None
        if self._guard_server_state is not None:
            _release(self._guard_server_state, self._guard_address)
        self._guard_address = None
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        feed_within_queue(self, data, self._guard_queue_limit, super().data_received)

    def _handshake_timed_out(self, transport: asyncio.BaseTransport, loop: asyncio.AbstractEventLoop) -> None:
        self._guard_timer = None
        if not _handshake_answered(self):
            log.debug("closing a WebSocket whose handshake was not answered in time")
            _close(transport, loop, answer=False)


def _handshake_answered(protocol: object) -> bool:
    """Whether uvicorn's WebSocket protocol has answered the handshake (websockets-sansio and wsproto keep
    ``handshake_complete``, the legacy websockets protocol an event)."""
    done = getattr(protocol, "handshake_complete", None)
    if isinstance(done, bool):
        return done
    event = getattr(protocol, "handshake_completed_event", None)
    return bool(event is not None and event.is_set())


_guarded_ws_classes: dict[type[asyncio.Protocol], type[asyncio.Protocol]] = {}


def guarded_ws_protocol(base: type[asyncio.Protocol]) -> type[asyncio.Protocol]:
    """uvicorn's WebSocket protocol class ``base`` with :class:`_WebSocketGuard` mixed in (made once per class)."""
    if issubclass(base, _WebSocketGuard):
        return base
    guarded = _guarded_ws_classes.get(base)
    if guarded is None:
        guarded = type(f"Guarded{base.__name__}", (_WebSocketGuard, base), {"__module__": __name__})
        _guarded_ws_classes[base] = guarded
    return guarded


__all__ = ["ConnectionLimits", "GuardedHttpToolsProtocol", "REQUEST_TIMEOUT_RESPONSE", "address_key",
           "guarded_ws_protocol", "limits_for", "open_connections"]

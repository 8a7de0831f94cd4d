"""WebSocket ``/v1/stream`` (docs/protocol.md): the handshake checks, then the connection's messages, each
within the connection's budgets (:mod:`service.sessions.message_budget`), handed one at a time to its
:class:`~service.sessions.protocol.Session` until the client leaves."""

from __future__ import annotations

import logging

from fastapi import APIRouter, WebSocket

from service.caller import Caller
from service.errors import ServiceError, error_response
from service.http.auth import check_access, key_from
from service.sessions.message_budget import MessageBudget, close_flooded
from service.sessions.protocol import Session
from service.state import ServiceState
from service.streaming.connection import Connection

log = logging.getLogger(__name__)
router = APIRouter()


@router.websocket("/v1/stream")
async def stream(ws: WebSocket) -> None:
    state: ServiceState = ws.app.state.service
    settings = state.settings
    encoding = ws.query_params.get("encoding", "json")
    try:
        caller, bucket = _admit(ws, state, encoding)
        await MessageBudget.admit(state, bucket)
    except ServiceError as exc:
        state.metrics.errors.labels(exc.code).inc()
        await _deny(ws, exc)
        return
    await ws.accept()
    conn = Connection(ws, encoding, send_queue_frames=settings.send_queue_frames,
                      slow_client_grace_s=settings.slow_client_grace_s, idle_timeout_s=settings.idle_timeout_s,
                      max_pending_messages=settings.max_pending_messages, metrics=state.metrics)
    conn.owner = caller.owner
    state.connections.add(conn)
    state.metrics.live_streams.inc()
    session = Session(state, conn, caller, bucket)
    budget = MessageBudget(state, conn, bucket)
    conn.start(settings.ws_send_buffer_bytes)
    conn.send_message(session.hello())
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            conn.touch()
            if conn.closing:
                continue
            flooded = budget.spend()  # before any of the message is read
            if flooded is not None:
                budget.charge_unread()
                await close_flooded(conn, flooded)
                break
            await session.handle(message)
    except Exception:  # a vanished client surfaces here as various errors: the cleanup below is all we need
        log.debug("stream ended with an error", exc_info=True)
    finally:
        await conn.shutdown()
        state.connections.discard(conn)
        state.metrics.live_streams.dec()


def _admit(ws: WebSocket, state: ServiceState, encoding: str) -> tuple[Caller, str]:
    """The caller and its rate-limit bucket (its key, or its address without keys), or raise the error that
    refuses this handshake: not serving, key or rate limit, then bad encoding (after the key, so that nothing
    about the request is answered to a client without one)."""
    if state.stopping:
        raise ServiceError("shutting_down", "the server is shutting down; reconnect to another replica")
    if state.registry is None:
        raise ServiceError("not_ready", "the models are still loading; retry shortly")
    client = ws.client.host if ws.client else "unknown"
    key = key_from(ws.headers, ws.query_params)
    caller = check_access(state, key, client)
    if encoding not in ("json", "binary"):
        raise ServiceError("validation_error", f"encoding must be 'json' or 'binary', got {encoding!r}")
    # The same bucket as the caller's HTTP requests: each client message costs one request.
    return caller, key if state.settings.auth_enabled and key is not None else client


async def _deny(ws: WebSocket, exc: ServiceError) -> None:
    """Refuse the handshake with an HTTP error in the envelope (403 close where the server cannot)."""
    try:
        await ws.send_denial_response(error_response(exc.code, exc.message, exc.headers))
    except RuntimeError:
        await ws.close(code=1008, reason=exc.message[:120])

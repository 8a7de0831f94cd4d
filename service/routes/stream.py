"""WebSocket ``/v1/stream`` (docs/protocol.md): characters driven frame by frame, several per connection.

This module reads and validates client messages and turns them into scheduler calls; the
outgoing side (queue, pacing, flow control, closing) is :mod:`service.connection`, the stepping
is :mod:`service.scheduler`. Messages of one connection are handled in order, one at a time.
"""

from __future__ import annotations

import logging
import time
from typing import Any

import orjson
from fastapi import APIRouter, WebSocket
from pydantic import ValidationError

from service.auth import check_access, key_from
from service.connection import CLOSE_TOO_BIG, Connection
from service.engine_jobs import lookup_style, prepare_character, resolve_style
from service.errors import ServiceError, describe_validation, error_response
from service.frames import floats_per_frame, frame_layout
from service.motion import motion_to_clip
from service.registry import LoadedModel
from service.scheduler import Stream
from service.schemas import (
    CLIENT_MESSAGE,
    CLIENT_TYPES,
    CancelMessage,
    PingMessage,
    RetargetMessage,
    StartMessage,
    StyleMessage,
)
from service.state import ServiceState

log = logging.getLogger(__name__)
router = APIRouter()
PROTOCOL = 1


@router.websocket("/v1/stream")
async def stream(ws: WebSocket) -> None:
    state: ServiceState = ws.app.state.service
    settings = state.settings
    encoding = ws.query_params.get("encoding", "json")
    try:
        if encoding not in ("json", "binary"):
            raise ServiceError("validation_error", f"encoding must be 'json' or 'binary', got {encoding!r}")
        if state.stopping:
            raise ServiceError("shutting_down", "the server is shutting down; reconnect to another replica")
        if state.registry is None:
            raise ServiceError("not_ready", "the models are still loading; retry shortly")
        client = ws.client.host if ws.client else "unknown"
        check_access(state, key_from(ws.headers, ws.query_params), client)
    except ServiceError as exc:
        state.metrics.errors.labels(exc.code).inc()
        await _deny(ws, exc)
        return
    await ws.accept()
    conn = Connection(ws, encoding, send_queue_frames=settings.send_queue_frames,
                      slow_client_grace_s=settings.slow_client_grace_s, idle_timeout_s=settings.idle_timeout_s,
                      max_pending_messages=settings.max_pending_messages, metrics=state.metrics)
    state.connections.add(conn)
    state.metrics.live_streams.inc()
    session = _Session(state, conn)
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
            await session.handle(message)
    except Exception:  # a vanished client surfaces here as various errors: the cleanup below is all we need
        log.debug("stream ended with an error", exc_info=True)
    finally:
        await conn.shutdown()
        state.connections.discard(conn)
        state.metrics.live_streams.dec()


async def _deny(ws: WebSocket, exc: ServiceError) -> None:
    """Refuse the handshake with an HTTP error in the envelope (403 close where the server cannot)."""
    try:
        await ws.send_denial_response(error_response(exc.code, exc.message, exc.headers))
    except RuntimeError:
        await ws.close(code=1008, reason=exc.message[:120])


class _Session:
    """The message handlers of one connection."""

    def __init__(self, state: ServiceState, conn: Connection) -> None:
        self.state = state
        self.conn = conn
        self.settings = state.settings
        assert state.registry is not None
        self.registry = state.registry

    def hello(self) -> dict[str, Any]:
        model = self.registry.get()
        info = model.info()
        return {
            "type": "hello",
            "protocol": PROTOCOL,
            "model": info,
            "frame_layout": frame_layout(len(info["skeleton"]["joints"])),
            "encoding": self.conn.encoding,
            "limits": {
                "max_characters": self.settings.max_characters_per_connection,
                "send_queue_frames": self.settings.send_queue_frames,
                "idle_timeout_s": self.settings.idle_timeout_s,
                "max_message_bytes": self.settings.ws_max_message_bytes,
                "max_transition_frames": model.max_transition,
            },
        }

    def error(self, code: str, message: str, character: str | None = None, request_id: Any = None) -> None:
        self.state.metrics.errors.labels(code).inc()
        out: dict[str, Any] = {"type": "error", "code": code, "message": message}
        if character is not None:
            out["character"] = character
        if request_id is not None:
            out["request_id"] = request_id
        self.conn.send_message(out)

    async def handle(self, message: dict[str, Any]) -> None:
        text = message.get("text")
        if text is None:
            data = message.get("bytes") or b""
            if len(data) > self.settings.ws_max_message_bytes:
                await self.conn.close(CLOSE_TOO_BIG, "message too big")
                return
            self.error("validation_error", "binary messages are not accepted from clients: send JSON text messages")
            return
        if len(text) > self.settings.ws_max_message_bytes or len(text.encode()) > self.settings.ws_max_message_bytes:
            await self.conn.close(CLOSE_TOO_BIG, f"message over {self.settings.ws_max_message_bytes} bytes")
            return
        try:
            obj = orjson.loads(text)
        except orjson.JSONDecodeError as exc:
            self.error("invalid_json", f"the message is not valid JSON: {exc}")
            return
        if not isinstance(obj, dict):
            self.error("validation_error", "a message must be a JSON object with a \"type\"")
            return
        rid = obj.get("request_id")
        rid = rid if isinstance(rid, (str, int)) and not isinstance(rid, bool) and len(str(rid)) <= 128 else None
        kind = obj.get("type")
        character = obj.get("character") if isinstance(obj.get("character"), str) else None
        if kind not in CLIENT_TYPES:
            self.error("validation_error", f"unknown message type {kind!r}; known: {', '.join(CLIENT_TYPES)}",
                       character, rid)
            return
        try:
            msg = CLIENT_MESSAGE.validate_python(obj)
        except ValidationError as exc:
            self.error("validation_error", describe_validation(exc.errors(include_url=False)), character, rid)
            return
        self.conn.busy += 1
        try:
            if isinstance(msg, StartMessage):
                await self.start(msg)
            elif isinstance(msg, RetargetMessage):
                await self.retarget(msg)
            elif isinstance(msg, StyleMessage):
                await self.style(msg)
            elif isinstance(msg, CancelMessage):
                self.cancel(msg)
            elif isinstance(msg, PingMessage):
                self.conn.send_message({"type": "pong", "id": msg.id, "server_time": time.time()})
        except ServiceError as exc:
            self.error(exc.code, exc.message, character, rid)
        except Exception:
            log.exception("stream message %s failed", kind)
            self.error("internal", "internal error; the server log has the details", character, rid)
        finally:
            self.conn.busy -= 1
            self.conn.touch()

    # ------------------------------------------------------------------ messages
    async def start(self, msg: StartMessage) -> None:
        conn, settings = self.conn, self.settings
        model = self.registry.get(msg.model)
        model.check_frames(msg.frames)
        cid = msg.character or conn.next_character_id()
        if cid in conn.streams or cid in conn.reserved:
            raise ServiceError("character_exists", f"character {cid!r} is already live on this connection; "
                                                   "cancel it first or pick another id")
        if len(conn.streams) + len(conn.reserved) >= settings.max_characters_per_connection:
            raise ServiceError("too_many_characters", f"this connection already drives "
                                                      f"{settings.max_characters_per_connection} characters (the limit)")
        if self.registry.live_characters() + self.state.reserved_characters >= settings.max_characters:
            raise ServiceError("too_many_characters", f"the server is at its limit of {settings.max_characters} "
                                                      "live characters; retry later or use another replica")
        conn.reserved.add(cid)
        self.state.reserved_characters += 1
        began = time.perf_counter()
        try:
            character, style, seed = await model.run(prepare_character, model, msg, cid)
            self.state.metrics.prepare_seconds.labels(model.name).observe(time.perf_counter() - began)
        finally:
            conn.reserved.discard(cid)
            self.state.reserved_characters -= 1
        if conn.closing:
            return
        assert model.scheduler is not None
        stream = Stream(character=character, outbox=conn, slot=conn.next_slot(), pace=msg.pace,
                        fps=float(model.engine.config.fps), encoding=conn.encoding)
        conn.streams[cid] = stream
        conn.send_message({"type": "started", "character": cid, "slot": stream.slot, "frames": msg.frames,
                           "fps": stream.fps, "style_id": style.style_id, "pace": msg.pace, "model": model.name,
                           "seed": None if msg.deterministic else seed,
                           "floats_per_frame": floats_per_frame(model.engine.skeleton.num_joints)})
        model.scheduler.add(stream)

    def _live(self, cid: str) -> tuple[Stream, LoadedModel]:
        stream = self.conn.streams.get(cid)
        if stream is None:
            raise ServiceError("unknown_character", f"no live character {cid!r} on this connection")
        return stream, self.registry.get(stream.model)

    async def retarget(self, msg: RetargetMessage) -> None:
        stream, model = self._live(msg.character)
        if msg.frames is not None:
            model.check_frames(msg.frames)
        target = None
        if msg.target is not None:
            target = await model.run(motion_to_clip, msg.target, model.engine, model.limits, "target")
        assert stream.scheduler is not None
        from_seq = await stream.scheduler.retarget(stream, target, msg.frames)
        self.conn.send_message({"type": "retargeted", "character": msg.character, "from_seq": from_seq})

    async def style(self, msg: StyleMessage) -> None:
        stream, model = self._live(msg.character)
        if msg.style_id is not None:
            style = lookup_style(model, msg.style_id)
        else:
            style = await model.run(resolve_style, model, None, msg.style)
        assert stream.scheduler is not None
        from_seq = await stream.scheduler.set_style(stream, style)
        self.conn.send_message({"type": "style_changed", "character": msg.character, "from_seq": from_seq,
                                "style_id": style.style_id})

    def cancel(self, msg: CancelMessage) -> None:
        stream, _ = self._live(msg.character)
        self.conn.cancel(stream)

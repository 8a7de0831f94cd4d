"""The client side of the ``/v1/stream`` protocol (docs/protocol.md) for one connection: the ``hello``,
then each client message read, validated and turned into scheduler calls, with its answer or error.

The outgoing side (queue, pacing, flow control, closing) is :mod:`service.streaming.connection`, the
stepping :mod:`service.streaming.scheduler`. Messages of one connection are handled in order, one at a time.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping
from typing import Any

import orjson
from pydantic import ValidationError

from service.caller import Caller
from service.engine_jobs import check_frames, reach_body
from service.errors import ServiceError, describe_validation
from service.motion import motion_to_clip
from service.placed_targets import prepare_character_at
from service.registry import LoadedModel
from service.schemas import (
    CLIENT_MESSAGE,
    CLIENT_TYPES,
    CancelMessage,
    ClientMessage,
    PingMessage,
    RetargetMessage,
    StartMessage,
    StyleMessage,
)
from service.state import ServiceState
from service.streaming.connection import CLOSE_TOO_BIG, Connection
from service.streaming.frames import floats_per_frame, frame_layout
from service.streaming.stream import Stream
from service.styles import lookup_style, on_lane, registered_style, resolve_style

log = logging.getLogger(__name__)
PROTOCOL = 1


def request_id(obj: dict[str, Any]) -> str | int | None:
    """The message's ``request_id`` when it is one that can be echoed (a short string or an integer)."""
    rid = obj.get("request_id")
    return rid if isinstance(rid, (str, int)) and not isinstance(rid, bool) and len(str(rid)) <= 128 else None


class Session:
    """The message handlers of one connection."""

    def __init__(self, state: ServiceState, conn: Connection, caller: Caller, bucket: str | None = None) -> None:
        self.state = state
        self.conn = conn
        self.caller = caller  # whose registered styles ``style_id`` names
        self.bucket = bucket  # the rate limit's bucket (the key, or the address): every message costs a request
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
                "max_transition_frames": model.engine.max_frames,
            },
        }

    def error(self, code: str, message: str, character: str | None = None, rid: str | int | None = None,
              retry_after_s: int | None = None) -> None:
        self.state.metrics.errors.labels(code).inc()
        out: dict[str, Any] = {"type": "error", "code": code, "message": message}
        if character is not None:
            out["character"] = character
        if rid is not None:
            out["request_id"] = rid
        if retry_after_s is not None:
            out["retry_after_s"] = retry_after_s
        self.conn.send_message(out)

    async def handle(self, message: Mapping[str, Any]) -> None:
        """Handle one received WebSocket message; whatever goes wrong is answered with an ``error`` message
        (or, for a message over the size limit, by closing with 1009)."""
        text = await self._text(message)
        if text is None or self._rate_limited(text):
            return
        parsed = self._parse(text)
        if parsed is None:
            return
        msg, character, rid = parsed
        self.conn.busy += 1
        try:
            await self._dispatch(msg)
        except ServiceError as exc:
            self.error(exc.code, exc.message, character, rid)
        except Exception:
            log.exception("stream message %s failed", msg.type)
            self.error("internal", "internal error; the server log has the details", character, rid)
        finally:
            self.conn.busy -= 1
            self.conn.touch()

    def _rate_limited(self, text: str) -> bool:
        """Spend a token of the connection's rate-limit bucket (that of its key's HTTP requests too); when there
        is none, answer ``rate_limited`` (with ``retry_after_s``) and drop the message."""
        limiter = self.state.limiter
        if self.bucket is None or not limiter.enabled:
            return False
        wait = limiter.take(self.bucket)
        if wait <= 0:
            return False
        try:
            obj = orjson.loads(text)
        except orjson.JSONDecodeError:
            obj = None
        obj = obj if isinstance(obj, dict) else {}
        character = obj.get("character") if isinstance(obj.get("character"), str) else None
        retry = max(1, math.ceil(wait))
        self.error("rate_limited", f"rate limit of {self.settings.rate_limit_per_s:g} requests/s (burst "
                                   f"{self.settings.rate_limit_burst}) exceeded, counting every message of this "
                                   f"connection; this {obj.get('type', 'message')!s:.20} was dropped: retry in "
                                   f"{wait:.2f} s", character, request_id(obj), retry_after_s=retry)
        return True

    async def _text(self, message: Mapping[str, Any]) -> str | None:
        """The message's text, or None once a binary or oversized message has been answered."""
        limit = self.settings.ws_max_message_bytes
        text = message.get("text")
        if text is None:
            data = message.get("bytes") or b""
            if len(data) > limit:
                await self.conn.close(CLOSE_TOO_BIG, "message too big")
            else:
                self.error("validation_error", "binary messages are not accepted from clients: send JSON text messages")
            return None
        if len(text) > limit or len(text.encode()) > limit:
            await self.conn.close(CLOSE_TOO_BIG, f"message over {limit} bytes")
            return None
        return text

    def _parse(self, text: str) -> tuple[ClientMessage, str | None, str | int | None] | None:
        """The validated message with its character and request id, or None once its error has been sent."""
        try:
            obj = orjson.loads(text)
        except orjson.JSONDecodeError as exc:
            self.error("invalid_json", f"the message is not valid JSON: {exc}")
            return None
        if not isinstance(obj, dict):
            self.error("validation_error", "a message must be a JSON object with a \"type\"")
            return None
        rid = request_id(obj)
        kind = obj.get("type")
        character = obj.get("character") if isinstance(obj.get("character"), str) else None
        if kind not in CLIENT_TYPES:
            self.error("validation_error", f"unknown message type {kind!r}; known: {', '.join(CLIENT_TYPES)}",
                       character, rid)
            return None
        try:
            msg: ClientMessage = CLIENT_MESSAGE.validate_python(obj)
        except ValidationError as exc:
            self.error("validation_error", describe_validation(exc.errors(include_url=False)), character, rid)
            return None
        return msg, character, rid

    async def _dispatch(self, msg: ClientMessage) -> None:
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

    # ------------------------------------------------------------------ messages
    async def start(self, msg: StartMessage) -> None:
        conn = self.conn
        model = self.registry.get(msg.model)
        check_frames(model, msg.frames)
        cid = msg.character or conn.next_character_id()
        self._check_room(cid)
        conn.reserved.add(cid)
        self.state.reserved_characters += 1
        began = time.perf_counter()
        try:
            registered = await registered_style(self.state.store_lane, model, self.caller, msg.style_id)  # the store's lane
            character, style, seed = await model.run_stream(prepare_character_at, model, self.caller, msg, cid,
                                                              registered, owner=self.caller.owner)
            self.state.metrics.prepare_seconds.labels(model.name).observe(time.perf_counter() - began)
        finally:
            conn.reserved.discard(cid)
            self.state.reserved_characters -= 1
        if conn.closing:
            return
        assert model.scheduler is not None
        stream = Stream(character=character, outbox=conn, slot=conn.next_slot(), pace=msg.pace,
                        fps=float(model.engine.config.fps), encoding=conn.encoding, owner=conn.owner)
        conn.streams[cid] = stream
        conn.send_message({"type": "started", "character": cid, "slot": stream.slot, "frames": msg.frames,
                           "fps": stream.fps, "style_id": style.style_id, "pace": msg.pace, "model": model.name,
                           "seed": None if msg.deterministic else seed,
                           "floats_per_frame": floats_per_frame(model.engine.skeleton.num_joints),
                           "reach": reach_body(character)})
        model.scheduler.add(stream)

    def _check_room(self, cid: str) -> None:
        """Refuse a start whose id is taken, or that would go over the connection's or the server's limit."""
        conn, settings = self.conn, self.settings
        if cid in conn.streams or cid in conn.reserved:
            raise ServiceError("character_exists", f"character {cid!r} is already live on this connection; "
                                                   "cancel it first or pick another id")
        if len(conn.streams) + len(conn.reserved) >= settings.max_characters_per_connection:
            raise ServiceError("too_many_characters", f"this connection already drives "
                                                      f"{settings.max_characters_per_connection} characters (the limit)")
        if self.registry.live_characters() + self.state.reserved_characters >= settings.max_characters:
            raise ServiceError("too_many_characters", f"the server is at its limit of {settings.max_characters} "
                                                      "live characters; retry later or use another replica")
        share = settings.characters_per_key
        if share is not None:
            owner = conn.owner
            mine = sum(len(c.streams) + len(c.reserved) for c in self.state.connections if c.owner == owner)
            if mine >= share:
                raise ServiceError("too_many_characters", f"this API key already drives {share} live characters, its "
                                                          "share of the server (RSMT_MAX_CHARACTERS_PER_KEY); retry "
                                                          "when some have ended")

    def _live(self, cid: str) -> tuple[Stream, LoadedModel]:
        stream = self.conn.streams.get(cid)
        if stream is None:
            raise ServiceError("unknown_character", f"no live character {cid!r} on this connection")
        return stream, self.registry.get(stream.model)

    async def retarget(self, msg: RetargetMessage) -> None:
        stream, model = self._live(msg.character)
        if msg.frames is not None:
            check_frames(model, msg.frames)
        target = None
        if msg.target is not None:
            target = await model.run_stream(motion_to_clip, msg.target, model.engine, model.limits, "target",
                                           owner=self.caller.owner)
        assert stream.scheduler is not None
        from_seq = await stream.scheduler.retarget(stream, target, msg.frames)
        self.conn.send_message({"type": "retargeted", "character": msg.character, "from_seq": from_seq,
                                "reach": reach_body(stream.character)})

    async def style(self, msg: StyleMessage) -> None:
        stream, model = self._live(msg.character)
        if msg.style_id is not None:
            style = await on_lane(self.state.store_lane, lookup_style, model, self.caller, msg.style_id)  # may reach Redis
        else:
            style = await model.run_stream(resolve_style, model, self.caller, None, msg.style, owner=self.caller.owner)
        assert stream.scheduler is not None
        from_seq = await stream.scheduler.set_style(stream, style)
        self.conn.send_message({"type": "style_changed", "character": msg.character, "from_seq": from_seq,
                                "style_id": style.style_id, "reach": reach_body(stream.character)})

    def cancel(self, msg: CancelMessage) -> None:
        stream, _ = self._live(msg.character)
        self.conn.cancel(stream)

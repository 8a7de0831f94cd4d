"""The ``/v1/stream`` protocol without I/O: messages out, frames and messages in, one character's traffic gathered.

:class:`StreamSession` is everything a stream client knows once ``hello`` has arrived: the model,
the binary frame layouts, which slot is which character, the traffic read but not yet claimed.
It builds and checks what is sent (:meth:`StreamSession.encode`), reads what arrives
(:meth:`StreamSession.parse`) and files it per character (:meth:`StreamSession.take`). The sync
and async clients (:mod:`rsmt_client.stream`) only move text and bytes over their sockets.
"""

from __future__ import annotations

import itertools
import json
from collections import deque
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlencode, urlsplit, urlunsplit

import numpy as np

from rsmt_client._retry import parse_retry_after
from rsmt_client.errors import RsmtError
from rsmt_client.frames import Frame, FrameLayout, Message, frame_from_json
from rsmt_client.motion import Poses, motion_payload
from rsmt_client.motion_cuts import Cutter
from rsmt_client.placement import target_field
from rsmt_client.reach import Reach

# The largest message both clients accept from the server (a binary frame of a very large rig is far less).
MAX_MESSAGE_BYTES = 16 << 20
# The messages about a character that carry its reach notice (docs/api-contract.md, "Reach"); the last one holds.
NOTICES = ("started", "retargeted", "style_changed")


def stream_url(url: str, encoding: str = "json", token: str | None = None) -> str:
    """``ws(s)://host:port/v1/stream?encoding=...`` from an HTTP(S) or WS(S) base URL."""
    if encoding not in ("json", "binary"):
        raise ValueError(f"encoding must be 'json' or 'binary', got {encoding!r}")
    parts = urlsplit(url)
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme)
    if scheme is None:
        raise ValueError(f"URL {url!r} must start with http://, https://, ws:// or wss://")
    path = parts.path.rstrip("/")
    if not path.endswith("/v1/stream"):
        path += "/v1/stream"
    query = {"encoding": encoding}
    if token:
        query["token"] = token
    return urlunsplit((scheme, parts.netloc, path, urlencode(query), ""))


def handshake_headers(api_key: str | None, token_in_query: bool) -> dict[str, str]:
    """The handshake's headers: the key as ``X-API-Key`` unless it travels in the URL (``?token=``)."""
    return {"X-API-Key": api_key} if api_key and not token_in_query else {}


@dataclass
class StreamResult:
    """What one character produced: its frames, the ``end`` message and the other messages about it; ``reach``, the
    last reach notice (its ``started`` or latest ``retargeted`` or ``style_changed``), says whether it arrived or
    stopped short."""

    character: str
    fps: float
    frames: list[Frame] = field(default_factory=list)
    end: Message | None = None
    messages: list[Message] = field(default_factory=list)

    @property
    def reach(self) -> Reach | None:
        """The notice of the last ``started`` / ``retargeted`` / ``style_changed`` that carried one (None: none did,
        as for a model without gait limits; a style switch works the reach out again at the new style's speed)."""
        notices = [m for m in self.messages if m.get("type") in NOTICES and m.get("reach")]
        return Reach.from_message(notices[-1]) if notices else None

    @property
    def stopped_short(self) -> bool:
        """Whether the last target was out of reach, so the character ended short of it (``reach.short_cm``)."""
        reach = self.reach
        return reach is not None and not reach.feasible

    def poses(self, joints: tuple[str, ...] | None = None) -> Poses:
        roots = np.array([f.root_position for f in self.frames], dtype=np.float32).reshape(-1, 3)
        rots = np.array([f.rotations for f in self.frames], dtype=np.float32)
        return Poses(roots, rots, self.fps, joints=joints, reach=self.reach)


class StreamSession:
    """Protocol state of one connection, from its ``hello`` on."""

    _ids = itertools.count(1)

    def __init__(self, hello: Message) -> None:
        if not isinstance(hello, dict) or hello.get("type") != "hello":
            raise RsmtError("protocol", f"expected a hello message first, got {str(hello)[:200]}")
        if hello.get("protocol") != 1:
            raise RsmtError("protocol", f"server speaks protocol {hello.get('protocol')}; this client speaks 1")
        self.hello = hello
        self.model: dict[str, Any] = hello["model"]
        self.joint_names = tuple(j["name"] for j in self.model["skeleton"]["joints"])
        self.layout = FrameLayout(hello["frame_layout"], len(self.joint_names))
        self.fps = float(self.model["fps"])
        self.slots: dict[int, str] = {}
        self.slot_layouts: dict[int, FrameLayout] = {}  # characters of another model than hello's
        self.pending: deque[Frame | Message] = deque()

    @classmethod
    def from_hello(cls, raw: str | bytes) -> StreamSession:
        """A session from the first message the server sent."""
        if isinstance(raw, bytes):
            raise RsmtError("protocol", "expected a hello message first, got a binary frame")
        try:
            return cls(json.loads(raw))
        except ValueError as exc:
            raise RsmtError("protocol", f"the first message is not JSON: {raw[:200]!r}") from exc

    # ------------------------------------------------------------------ receiving
    def parse(self, raw: str | bytes) -> Frame | Message:
        """A received WebSocket message as a :class:`Frame` (binary or JSON ``frame``) or a message dict."""
        if isinstance(raw, bytes):
            slot = self.layout.slot_of(raw)
            layout = self.slot_layouts.get(slot, self.layout) if slot is not None else self.layout
            return layout.decode(raw, self.slots)
        msg = json.loads(raw)
        kind = msg.get("type")
        if kind == "started":
            slot = int(msg["slot"])
            self.slots[slot] = msg["character"]
            fpf = msg.get("floats_per_frame")
            if fpf is not None and int(fpf) != self.layout.floats_per_frame:
                self.slot_layouts[slot] = self.layout.resized(int(fpf))
            else:
                self.slot_layouts.pop(slot, None)
        elif kind == "frame":
            return frame_from_json(msg)
        return msg

    def next_pending(self) -> Frame | Message | None:
        """The oldest item read while collecting another character, if any."""
        return self.pending.popleft() if self.pending else None

    def take(self, item: Frame | Message, result: StreamResult) -> bool:
        """File ``item`` into ``result`` if it is about that character (True once it ended); queue it otherwise.

        An ``error`` about this character (or about none) raises :class:`RsmtError`.
        """
        c = result.character
        if isinstance(item, Frame):
            if item.character == c:
                result.frames.append(item)
            else:
                self.pending.append(item)
            return False
        if item.get("type") == "error" and item.get("character") in (c, None):
            raise RsmtError(str(item.get("code")), str(item.get("message")), character=item.get("character"),
                            request_id=item.get("request_id"))
        if item.get("character") != c:
            self.pending.append(item)
            return False
        if item.get("type") == "end":
            result.end = item
            return True
        result.messages.append(item)
        return False

    def begin_collect(self, character: str) -> tuple[StreamResult, bool]:
        """A result for ``character`` with the queued traffic about it filed, and whether it already ended.

        What stays queued keeps its arrival order for later ``recv`` calls.
        """
        result = StreamResult(character, self.fps)
        queued = list(self.pending)
        self.pending.clear()
        for i, item in enumerate(queued):
            if self.take(item, result):
                self.pending.extend(queued[i + 1:])
                return result, True
        return result, False

    @staticmethod
    def collect_timeout(character: str, timeout: float) -> RsmtError:
        return RsmtError("timeout", f"character {character!r} did not end within {timeout} s")

    def transition_poses(self, result: StreamResult) -> Poses:
        """A streamed transition's frames as :class:`Poses`, with the style and model its ``started`` named."""
        poses = result.poses(self.joint_names)
        started = next((m for m in result.messages if m.get("type") == "started"), {})
        poses.style_id, poses.model = started.get("style_id"), started.get("model")
        return poses  # its reach: the latest (re)target's or style switch's notice (StreamResult.reach)

    # ------------------------------------------------------------------ sending
    def encode(self, message: Message) -> str:
        """The message as the server reads it, refused here when it is over the server's message limit.

        Sent anyway, the server would close the whole connection (1009) and every character on it with it.
        """
        text = json.dumps(message, separators=(",", ":"))
        limit = self.hello.get("limits", {}).get("max_message_bytes")
        size = len(text.encode())
        if limit is not None and size > int(limit):
            hint = ("register the style clip with Client.register_style and pass style_id"
                    if "style" in message else "send fewer frames")
            raise RsmtError("message_too_large", f"this {message.get('type')} message is {size} bytes, over the "
                            f"server's limit of {int(limit)} per WebSocket message: {hint}")
        return text

    def fits(self, message: Message) -> bool:
        """Whether ``message`` is within the server's limit per WebSocket message."""
        limit = self.hello.get("limits", {}).get("max_message_bytes")
        return limit is None or len(json.dumps(message, separators=(",", ":")).encode()) <= int(limit)

    def fitted(self, message: Message, cuts: Cutter) -> Message:
        """``message`` with its context, target and style cut to what the model reads (:mod:`rsmt_client.motion_cuts`).

        ``cuts`` is for hello's model; a message for another model goes as it is."""
        if message.get("model") not in (None, self.model.get("name")):
            return message
        out = dict(message)
        for key, how in (("context", cuts.context), ("target", cuts.target), ("style", cuts.style)):
            if isinstance(out.get(key), dict):
                out[key] = how(out[key])
        return out

    @classmethod
    def new_id(cls) -> str:
        return f"py{next(cls._ids)}"

    @staticmethod
    def start_message(context: Any, target: Any, frames: int, style_id: str | None, style: Any, seed: int | None,
                      deterministic: bool, pace: str, character: str, model: str | None, request_id: Any,
                      exact_arrival: bool | None = None, style_strength: float | None = None) -> Message:
        if (style_id is None) == (style is None):
            raise ValueError("give exactly one of style_id or style")
        msg: Message = {"type": "start", "character": character, "context": motion_payload(context),
                        "frames": int(frames), "deterministic": bool(deterministic), "pace": pace}
        msg.update(target_field(target, lambda payload: payload))
        if style_id is not None:
            msg["style_id"] = style_id
        else:
            msg["style"] = motion_payload(style)
        for key, value in (("seed", seed), ("model", model), ("request_id", request_id)):
            if value is not None:
                msg[key] = value
        if exact_arrival is not None:  # sent only when said (None: the server's default, exact for target_at only),
            msg["exact_arrival"] = bool(exact_arrival)  # so older servers keep accepting the message
        if style_strength is not None:
            msg["style_strength"] = float(style_strength)
        return msg

    @staticmethod
    def retarget_message(character: str, target: Any, frames: int | None, request_id: Any) -> Message:
        if target is None and frames is None:
            raise ValueError("retarget needs a target and/or frames")
        msg: Message = {"type": "retarget", "character": character}
        if target is not None:
            msg["target"] = motion_payload(target)
        if frames is not None:
            msg["frames"] = int(frames)
        if request_id is not None:
            msg["request_id"] = request_id
        return msg

    @staticmethod
    def style_message(character: str, style_id: str | None, style: Any) -> Message:
        if (style_id is None) == (style is None):
            raise ValueError("give exactly one of style_id or style")
        msg: Message = {"type": "style", "character": character}
        if style_id is not None:
            msg["style_id"] = style_id
        else:
            msg["style"] = motion_payload(style)
        return msg

    @staticmethod
    def cancel_message(character: str) -> Message:
        return {"type": "cancel", "character": character}

    @staticmethod
    def ping_message(ident: Any) -> Message:
        return {"type": "ping", "id": ident}


# ---------------------------------------------------------------------- websockets' exceptions as contract errors

def closed_error(exc: Exception) -> RsmtError:
    """A ``ConnectionClosed`` as ``RsmtError("closed")`` with the close code."""
    rcvd = getattr(exc, "rcvd", None)
    code = getattr(rcvd, "code", None)
    reason = getattr(rcvd, "reason", "") or str(exc)
    return RsmtError("closed", f"the stream closed ({code}): {reason}", close_code=code)


def refused_handshake(exc: Exception) -> tuple[int, dict[str, str], RsmtError]:
    """The HTTP answer of a refused handshake (``InvalidStatus``), as (status, headers, error)."""
    response = getattr(exc, "response", None)
    if response is None:
        return 0, {}, RsmtError("protocol", f"the handshake failed: {exc}")
    status = int(response.status_code)
    headers = {k.lower(): v for k, v in response.headers.raw_items()}
    code, message = "http_error", f"handshake refused with {status}"
    try:
        err = json.loads(response.body or b"{}").get("error") or {}
        code, message = err.get("code", code), err.get("message", message)
    except (ValueError, AttributeError):
        pass
    return status, headers, RsmtError(code, message, status=status, retry_after=parse_retry_after(headers.get("retry-after")))

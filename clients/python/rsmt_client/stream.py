"""WebSocket clients of ``/v1/stream`` (the ``websockets`` library): :class:`StreamClient` and :class:`AsyncStreamClient`.

The server speaks first (``hello``: model, skeleton, binary ``frame_layout``, limits). The client
then sends ``start`` / ``retarget`` / ``style`` / ``cancel`` / ``ping`` and reads ``started``,
``frame``, ``end``, ``retargeted``, ``style_changed``, ``error`` and ``pong``. Frames come back as
:class:`Frame` whichever encoding was chosen: binary frames are decoded with the layout that
``hello`` declares, never with a hard-coded one.
"""

from __future__ import annotations

import asyncio
import itertools
import json
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Self
from urllib.parse import urlencode, urlsplit, urlunsplit

import numpy as np

from rsmt_client._retry import RetryPolicy, parse_retry_after
from rsmt_client.errors import RsmtError
from rsmt_client.http import DEFAULT_URL
from rsmt_client.motion import Poses, motion_payload

Message = dict[str, Any]


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


@dataclass(frozen=True)
class Frame:
    """One streamed pose: ``root_position [3]`` and local ``rotations [J, 4]`` (x, y, z, w), float32, model units."""

    character: str | None
    slot: int
    seq: int
    t: float
    remaining: int
    root_position: np.ndarray
    rotations: np.ndarray


class FrameLayout:
    """``hello.frame_layout``: where each field sits in a binary frame (little-endian float32)."""

    def __init__(self, layout: dict[str, Any], joints: int) -> None:
        if layout.get("encoding") != "float32-le":
            raise RsmtError("protocol", f"unsupported frame encoding {layout.get('encoding')!r} (this client reads float32-le)")
        self.floats_per_frame = int(layout["floats_per_frame"])
        self.fields = {f["name"]: (int(f["offset"]), int(f["count"])) for f in layout["fields"]}
        need = {"slot": 1, "seq": 1, "t": 1, "root_position": 3, "rotations": 4 * joints, "remaining": 1}
        for name, count in need.items():
            if name not in self.fields or self.fields[name][1] != count:
                raise RsmtError("protocol", f"frame_layout field {name!r} should hold {count} floats: {layout}")
            off, cnt = self.fields[name]
            if off < 0 or off + cnt > self.floats_per_frame:
                raise RsmtError("protocol", f"frame_layout field {name!r} lies outside the frame: {layout}")
        self.joints = joints

    def resized(self, floats_per_frame: int) -> FrameLayout:
        """The layout of a model with another joint count (``started.floats_per_frame``): the fields after
        the rotations move by the difference, the rest stay where hello put them."""
        delta = int(floats_per_frame) - self.floats_per_frame
        if delta == 0:
            return self
        if delta % 4 or self.joints + delta // 4 < 1:
            raise RsmtError("protocol", f"floats_per_frame {floats_per_frame} does not fit this layout")
        rot = self.fields["rotations"][0]
        fields = [{"name": n, "offset": o + delta if o > rot else o, "count": c + delta if n == "rotations" else c}
                  for n, (o, c) in self.fields.items()]
        return FrameLayout({"encoding": "float32-le", "floats_per_frame": floats_per_frame, "fields": fields},
                           self.joints + delta // 4)

    def slot_of(self, data: bytes) -> int | None:
        off = self.fields["slot"][0]
        if len(data) < 4 * (off + 1):
            return None
        return int(np.frombuffer(data, dtype="<f4", count=1, offset=4 * off)[0])

    def field(self, values: np.ndarray, name: str) -> np.ndarray:
        off, cnt = self.fields[name]
        return values[off:off + cnt]

    def decode(self, data: bytes, slots: dict[int, str] | None = None) -> Frame:
        if len(data) != 4 * self.floats_per_frame:
            raise RsmtError("protocol", f"binary frame of {len(data)} bytes; the layout says {4 * self.floats_per_frame}")
        v = np.frombuffer(data, dtype="<f4")
        slot = int(self.field(v, "slot")[0])
        return Frame(character=(slots or {}).get(slot), slot=slot, seq=int(self.field(v, "seq")[0]),
                     t=float(self.field(v, "t")[0]), remaining=int(self.field(v, "remaining")[0]),
                     root_position=self.field(v, "root_position").astype(np.float32),
                     rotations=self.field(v, "rotations").astype(np.float32).reshape(self.joints, 4))


def frame_from_json(msg: Message) -> Frame:
    """A JSON ``frame``; its numbers are the server's float32 values, so this equals the binary decoding."""
    pose = msg["pose"]
    rotations = np.asarray(pose["rotations"], dtype=np.float32)
    if rotations.ndim != 2 or rotations.shape[1] != 4:
        raise RsmtError("protocol", f"frame pose.rotations must be [joints][4], got shape {list(rotations.shape)}")
    return Frame(character=msg.get("character"), slot=int(msg.get("slot", -1)), seq=int(msg["seq"]),
                 t=float(np.float32(msg["t"])), remaining=int(msg.get("remaining", 0)),
                 root_position=np.asarray(pose["root_position"], dtype=np.float32).reshape(3), rotations=rotations)


@dataclass
class StreamResult:
    """What one character produced: its frames, the ``end`` message and the other messages about it."""

    character: str
    fps: float
    frames: list[Frame] = field(default_factory=list)
    end: Message | None = None
    messages: list[Message] = field(default_factory=list)

    def poses(self, joints: tuple[str, ...] | None = None) -> Poses:
        roots = np.array([f.root_position for f in self.frames], dtype=np.float32).reshape(-1, 3)
        rots = np.array([f.rotations for f in self.frames], dtype=np.float32)
        return Poses(roots, rots, self.fps, joints=joints)


class _Session:
    """Protocol state shared by both clients: hello, slot to character map, message building and parsing."""

    _ids = itertools.count(1)

    def __init__(self, hello: Message) -> None:
        if hello.get("type") != "hello":
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

    def parse(self, raw: str | bytes) -> Frame | Message:
        if isinstance(raw, bytes):
            layout = self.slot_layouts.get(self.layout.slot_of(raw), self.layout)  # type: ignore[arg-type]
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

    def encode(self, message: Message) -> str:
        """The message as the server reads it, refused here when it is over the server's message limit.

        Sent anyway, the server would close the whole connection (1009) and every character on it with it.
        """
        text = json.dumps(message, separators=(",", ":"))
        limit = self.hello.get("limits", {}).get("max_message_bytes")
        size = len(text.encode())
        if limit is not None and size > int(limit):
            hint = ("register the style clip with Client.register_style and pass style_id"
                    if "style" in message else "send fewer context frames")
            raise RsmtError("message_too_large", f"this {message.get('type')} message is {size} bytes, over the "
                            f"server's limit of {int(limit)} per WebSocket message: {hint}")
        return text

    @classmethod
    def new_id(cls) -> str:
        return f"py{next(cls._ids)}"

    @staticmethod
    def start_message(context: Any, target: Any, frames: int, style_id: str | None, style: Any, seed: int | None,
                      deterministic: bool, pace: str, character: str, model: str | None, request_id: Any,
                      exact_arrival: bool = False) -> Message:
        if (style_id is None) == (style is None):
            raise ValueError("give exactly one of style_id or style")
        msg: Message = {"type": "start", "character": character, "context": motion_payload(context),
                        "target": motion_payload(target), "frames": int(frames), "deterministic": bool(deterministic),
                        "pace": pace}
        if style_id is not None:
            msg["style_id"] = style_id
        else:
            msg["style"] = motion_payload(style)
        for key, value in (("seed", seed), ("model", model), ("request_id", request_id)):
            if value is not None:
                msg[key] = value
        if exact_arrival:  # sent only when asked, so older servers keep accepting the message
            msg["exact_arrival"] = True
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

    def take(self, item: Frame | Message, result: StreamResult) -> bool:
        """File ``item`` into ``result`` if it is about that character (True once it ended); queue it otherwise."""
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


def _closed_error(exc: Exception) -> RsmtError:
    rcvd = getattr(exc, "rcvd", None)
    code = getattr(rcvd, "code", None)
    reason = getattr(rcvd, "reason", "") or str(exc)
    return RsmtError("closed", f"the stream closed ({code}): {reason}", close_code=code)


def _denied(exc: Exception) -> tuple[int, dict[str, str], RsmtError] | None:
    """The HTTP answer of a refused handshake, as (status, headers, error)."""
    response = getattr(exc, "response", None)
    if response is None:
        return None
    status = int(response.status_code)
    headers = {k.lower(): v for k, v in response.headers.raw_items()}
    code, message = "http_error", f"handshake refused with {status}"
    try:
        err = json.loads(response.body or b"{}").get("error") or {}
        code, message = err.get("code", code), err.get("message", message)
    except (ValueError, AttributeError):
        pass
    return status, headers, RsmtError(code, message, status=status, retry_after=parse_retry_after(headers.get("retry-after")))


class StreamClient:
    """Synchronous ``/v1/stream`` client (``websockets.sync``); one connection, any number of characters.

    ``StreamClient(url, api_key=..., encoding="binary")`` connects, reads ``hello`` (``.hello``,
    ``.model``, ``.layout``), then: ``start(...)`` returns the character id; ``recv()`` gives the
    next :class:`Frame` or message dict; ``collect(character)`` reads until that character ends.
    A refused handshake (429, 503) is retried with the :class:`RetryPolicy`.
    """

    def __init__(self, url: str = DEFAULT_URL, api_key: str | None = None, encoding: str = "json",
                 retry: RetryPolicy | None = None, open_timeout: float = 30.0, token_in_query: bool = False,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        from websockets.exceptions import InvalidStatus
        from websockets.sync.client import connect

        self.url = stream_url(url, encoding, api_key if token_in_query else None)
        self.encoding = encoding
        headers = {"X-API-Key": api_key} if api_key and not token_in_query else {}
        policy = retry or RetryPolicy()
        retry_n = 0
        while True:
            try:
                self._ws = connect(self.url, additional_headers=headers, open_timeout=open_timeout, proxy=None,
                                   compression=None, max_size=16 << 20)
                break
            except InvalidStatus as exc:
                denied = _denied(exc)
                assert denied is not None
                status, hdrs, err = denied
                wait = policy.wait(retry_n, status, hdrs)
                if wait is None:
                    raise err from exc
            except OSError as exc:
                wait = policy.wait(retry_n, None, None)
                if wait is None:
                    raise RsmtError("connection", f"cannot reach {self.url}: {exc}") from exc
            sleep(wait)
            retry_n += 1
        self._session = _Session(json.loads(self._ws.recv(open_timeout)))

    # ------------------------------------------------------------------ state
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

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._ws.close()

    # ------------------------------------------------------------------ sending
    def send(self, message: Message) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            self._ws.send(self._session.encode(message))
        except ConnectionClosed as exc:
            raise _closed_error(exc) from exc

    def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
              seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
              character: str | None = None, model: str | None = None, request_id: Any = None,
              exact_arrival: bool = False) -> str:
        """Send ``start``; returns the character id (``character`` or a new one). Frames follow ``started``."""
        character = character or _Session.new_id()
        self.send(_Session.start_message(context, target, frames, style_id, style, seed, deterministic, pace,
                                         character, model, request_id, exact_arrival))
        return character

    def retarget(self, character: str, target: Any = None, frames: int | None = None, request_id: Any = None) -> None:
        self.send(_Session.retarget_message(character, target, frames, request_id))

    def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        self.send(_Session.style_message(character, style_id, style))

    def cancel(self, character: str) -> None:
        self.send({"type": "cancel", "character": character})

    def ping(self, ident: Any = None) -> None:
        self.send({"type": "ping", "id": ident})

    # ------------------------------------------------------------------ receiving
    def recv(self, timeout: float | None = None) -> Frame | Message:
        """The next frame or message (queued ones first); raises ``RsmtError("timeout")`` / ``("closed")``."""
        if self._session.pending:
            return self._session.pending.popleft()
        return self._recv_socket(timeout)

    def _recv_socket(self, timeout: float | None) -> Frame | Message:
        from websockets.exceptions import ConnectionClosed

        try:
            raw = self._ws.recv(timeout)
        except TimeoutError as exc:
            raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
        except ConnectionClosed as exc:
            raise _closed_error(exc) from exc
        return self._session.parse(raw)

    def collect(self, character: str, timeout: float = 60.0,
                on_frame: Callable[[StreamClient, Frame], None] | None = None) -> StreamResult:
        """Read until ``character`` ends; other characters' traffic stays queued for later ``recv`` calls.

        An ``error`` about this character (or about none) raises :class:`RsmtError`.
        """
        result = StreamResult(character, self._session.fps)
        deadline = time.monotonic() + timeout
        pending = list(self._session.pending)
        self._session.pending.clear()
        for i, item in enumerate(pending):
            if self._session.take(item, result):
                self._session.pending.extend(pending[i + 1:])  # keeps arrival order for later recv calls
                return result
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RsmtError("timeout", f"character {character!r} did not end within {timeout} s")
            item = self._recv_socket(left)
            n = len(result.frames)
            if self._session.take(item, result):
                return result
            if on_frame is not None and len(result.frames) > n:
                on_frame(self, result.frames[-1])

    def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                   seed: int | None = None, deterministic: bool = False, pace: str = "asap",
                   timeout: float = 60.0, exact_arrival: bool = False) -> Poses:
        """A whole transition over the stream (start, then collect): the same frames ``POST /v1/transition`` gives."""
        c = self.start(context, target, frames, style_id, style, seed, deterministic, pace, exact_arrival=exact_arrival)
        result = self.collect(c, timeout)
        poses = result.poses(self.joint_names)
        started = next((m for m in result.messages if m.get("type") == "started"), {})
        poses.style_id, poses.model = started.get("style_id"), started.get("model")
        return poses


class AsyncStreamClient:
    """The asyncio twin of :class:`StreamClient`: ``client = await AsyncStreamClient.connect(url)``."""

    def __init__(self, ws: Any, session: _Session, url: str, encoding: str) -> None:
        self._ws = ws
        self._session = session
        self.url = url
        self.encoding = encoding

    @classmethod
    async def connect(cls, url: str = DEFAULT_URL, api_key: str | None = None, encoding: str = "json",
                      retry: RetryPolicy | None = None, open_timeout: float = 30.0,
                      token_in_query: bool = False) -> AsyncStreamClient:
        from websockets.asyncio.client import connect
        from websockets.exceptions import InvalidStatus

        full = stream_url(url, encoding, api_key if token_in_query else None)
        headers = {"X-API-Key": api_key} if api_key and not token_in_query else {}
        policy = retry or RetryPolicy()
        retry_n = 0
        while True:
            try:
                ws = await connect(full, additional_headers=headers, open_timeout=open_timeout, proxy=None,
                                   compression=None, max_size=16 << 20)
                break
            except InvalidStatus as exc:
                denied = _denied(exc)
                assert denied is not None
                status, hdrs, err = denied
                wait = policy.wait(retry_n, status, hdrs)
                if wait is None:
                    raise err from exc
            except OSError as exc:
                wait = policy.wait(retry_n, None, None)
                if wait is None:
                    raise RsmtError("connection", f"cannot reach {full}: {exc}") from exc
            await asyncio.sleep(wait)
            retry_n += 1
        hello = json.loads(await asyncio.wait_for(ws.recv(), open_timeout))
        return cls(ws, _Session(hello), full, encoding)

    @property
    def hello(self) -> Message:
        return self._session.hello

    @property
    def model(self) -> dict[str, Any]:
        return self._session.model

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._session.joint_names

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self._ws.close()

    async def send(self, message: Message) -> None:
        from websockets.exceptions import ConnectionClosed

        try:
            await self._ws.send(self._session.encode(message))
        except ConnectionClosed as exc:
            raise _closed_error(exc) from exc

    async def start(self, context: Any, target: Any, frames: int, style_id: str | None = None, style: Any = None,
                    seed: int | None = None, deterministic: bool = False, pace: str = "realtime",
                    character: str | None = None, model: str | None = None, request_id: Any = None,
                    exact_arrival: bool = False) -> str:
        character = character or _Session.new_id()
        await self.send(_Session.start_message(context, target, frames, style_id, style, seed, deterministic, pace,
                                               character, model, request_id, exact_arrival))
        return character

    async def retarget(self, character: str, target: Any = None, frames: int | None = None,
                       request_id: Any = None) -> None:
        await self.send(_Session.retarget_message(character, target, frames, request_id))

    async def set_style(self, character: str, style_id: str | None = None, style: Any = None) -> None:
        await self.send(_Session.style_message(character, style_id, style))

    async def cancel(self, character: str) -> None:
        await self.send({"type": "cancel", "character": character})

    async def ping(self, ident: Any = None) -> None:
        await self.send({"type": "ping", "id": ident})

    async def recv(self, timeout: float | None = None) -> Frame | Message:
        if self._session.pending:
            return self._session.pending.popleft()
        return await self._recv_socket(timeout)

    async def _recv_socket(self, timeout: float | None) -> Frame | Message:
        from websockets.exceptions import ConnectionClosed

        try:
            raw = await asyncio.wait_for(self._ws.recv(), timeout)
        except TimeoutError as exc:
            raise RsmtError("timeout", f"nothing received within {timeout} s") from exc
        except ConnectionClosed as exc:
            raise _closed_error(exc) from exc
        return self._session.parse(raw)

    async def collect(self, character: str, timeout: float = 60.0) -> StreamResult:
        result = StreamResult(character, self._session.fps)
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        pending = list(self._session.pending)
        self._session.pending.clear()
        for i, item in enumerate(pending):
            if self._session.take(item, result):
                self._session.pending.extend(pending[i + 1:])  # keeps arrival order for later recv calls
                return result
        while True:
            left = deadline - loop.time()
            if left <= 0:
                raise RsmtError("timeout", f"character {character!r} did not end within {timeout} s")
            if self._session.take(await self._recv_socket(left), result):
                return result

    async def transition(self, context: Any, target: Any, frames: int, style_id: str | None = None,
                         style: Any = None, seed: int | None = None, deterministic: bool = False, pace: str = "asap",
                         timeout: float = 60.0, exact_arrival: bool = False) -> Poses:
        c = await self.start(context, target, frames, style_id, style, seed, deterministic, pace,
                             exact_arrival=exact_arrival)
        result = await self.collect(c, timeout)
        poses = result.poses(self.joint_names)
        started = next((m for m in result.messages if m.get("type") == "started"), {})
        poses.style_id, poses.model = started.get("style_id"), started.get("model")
        return poses

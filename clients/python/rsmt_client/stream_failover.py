"""Failover that resumes, without I/O: what a stream client must resend when its connection is lost.

:class:`Failover` watches what the client sends (``start``, ``retarget``, ``style``, ``cancel``) and what it
reads, and keeps for every live character its ``start`` as it stands now (target, style and frame count
updated by later messages), the last ``context_frames`` frames received and how many were delivered.
When the connection drops (its replica died, was restarted or drained), the client opens a new one
through the same URL (the load balancer picks a live replica) and sends :meth:`Failover.resume_messages`:
for each character a ``start`` whose context is the frames it received last, with the same target and
style, the frames it still had to go and ``retargeted`` when its target changed mid-motion. Frames of
the resumed character are renumbered so that ``seq`` and ``t`` carry on where they stopped,
``end.frames`` counts all of them, and the caller sees a stall of the reconnection's length, not an
error and not a lost character.

It also answers ``unknown_style`` (a style evicted, or registered on a store the new replica does not
share) by registering the clip again, when it holds the clip (:meth:`Failover.remember_style`), and
resending the message that named it; a resume refused for its ``retargeted`` option (a replica older
than it) is sent again without it. The sync and async clients (:mod:`rsmt_client.stream`) do the I/O.
"""

from __future__ import annotations

import copy
import dataclasses
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from rsmt_client.frames import Frame, Message
from rsmt_client.http_protocol import MAX_STYLE_CLIPS, default_style_name
from rsmt_client.motion import load_bvh_poses, motion_payload

# Close codes after which resuming would only repeat the failure: the client's own faults.
NO_RESUME_CLOSE_CODES = frozenset({1003, 1007, 1008, 1009})


def http_url(url: str) -> str:
    """The HTTP(S) base URL of a stream URL (``ws://host:port/v1/stream?...`` -> ``http://host:port``)."""
    parts = urlsplit(url)
    scheme = {"ws": "http", "wss": "https"}.get(parts.scheme, parts.scheme)
    path = parts.path.rstrip("/")
    path = path[: -len("/v1/stream")] if path.endswith("/v1/stream") else path
    return urlunsplit((scheme, parts.netloc, path, "", ""))


@dataclass
class _Character:
    """One live character as the failover sees it."""

    start: Message  # the start message as it stands now (target, style, frames updated)
    last_start: Message  # the start last sent for it: the original one, or the resume after a reconnection
    recent: deque[Frame]  # the last context_frames frames received, delivered numbering
    delivered: int = 0  # frames handed to the caller
    base: int = 0  # frames delivered before this connection's stream of it began
    remaining: int = 0  # frames still to come
    retarget_frames: int | None = None  # a retarget's frame count not yet seen in a frame
    retarget_from: int | None = None  # its from_seq, in this connection's numbering, once known
    retargeted: bool = False  # given a new target after its start: a resume from received frames says so
    awaiting_start: bool = True  # sent start (or resume), no started yet
    resent: bool = False  # the start awaited is a resume
    last_style: Message | None = None  # the last style message, to resend after registering its clip
    cancelled: bool = False


@dataclass
class Actions:
    """What the I/O layer does with one received item: hand ``item`` to the caller (None: swallow it),
    and first register the clip of ``register`` (style id, its ``POST /v1/styles`` body) and send ``send``."""

    item: Frame | Message | None
    register: tuple[str, dict[str, Any]] | None = None
    send: list[Message] = field(default_factory=list)


def style_body(motions: Sequence[Any], name: str | None, model: str | None) -> dict[str, Any]:
    """The ``POST /v1/styles`` body a stream client keeps for a style of one clip (``motion``) or several encoded
    together (``motions``), to register it again as it was; a ValueError for no clip or more than five."""
    if not 1 <= len(motions) <= MAX_STYLE_CLIPS:
        raise ValueError(f"a style is registered from 1 to {MAX_STYLE_CLIPS} clips; got {len(motions)}")
    payloads = [motion_payload(m) for m in motions]
    body: dict[str, Any] = {"name": name or default_style_name(motions[0])}
    body.update({"motion": payloads[0]} if len(payloads) == 1 else {"motions": payloads})
    if model is not None:
        body["model"] = model
    return body


class Failover:
    """Per-connection-independent resume state of one stream client (see the module doc)."""

    def __init__(self, context_frames: int, fps: float, joint_names: tuple[str, ...]) -> None:
        self.context_frames, self.fps, self.joint_names = int(context_frames), float(fps), tuple(joint_names)
        self.characters: dict[str, _Character] = {}
        self.styles: dict[str, dict[str, Any]] = {}  # style id -> POST /v1/styles body (name, motion, model)
        self.resumes = 0  # reconnections that resumed at least one character

    # ------------------------------------------------------------------ what the caller sends
    def sent(self, message: Message) -> None:
        kind, cid = message.get("type"), message.get("character")
        if kind == "start" and cid is not None:
            self.characters[cid] = _Character(copy.deepcopy(message), copy.deepcopy(message),
                                              deque(maxlen=self.context_frames), remaining=int(message["frames"]))
            return
        ch = self.characters.get(cid) if cid is not None else None
        if ch is None:
            return
        if kind == "retarget":
            if "target" in message:
                ch.start["target"] = copy.deepcopy(message["target"])
                ch.start.pop("target_at", None)  # a pose now: a start names one target or the other
                ch.retargeted = True
            if "frames" in message:
                ch.retarget_frames, ch.retarget_from = int(message["frames"]), None
        elif kind == "style":
            for key in ("style_id", "style"):
                ch.start.pop(key, None)
                if key in message:
                    ch.start[key] = copy.deepcopy(message[key])
            ch.last_style = copy.deepcopy(message)
        elif kind == "cancel":
            ch.cancelled = True

    def remember_style(self, style_id: str, body: dict[str, Any]) -> None:
        """Hold the ``POST /v1/styles`` body of ``style_id`` (:func:`style_body`) to register it again on
        ``unknown_style``."""
        self.styles[style_id] = body

    @property
    def live(self) -> bool:
        return any(not c.cancelled for c in self.characters.values())

    # ------------------------------------------------------------------ what arrives
    def received(self, item: Frame | Message) -> Actions:
        if isinstance(item, Frame):
            return Actions(self._frame(item))
        cid = item.get("character")
        ch = self.characters.get(cid) if isinstance(cid, str) else None
        if ch is None or not isinstance(cid, str):
            return Actions(item)
        kind = item.get("type")
        if kind == "started":
            resumed = ch.awaiting_start and ch.resent
            ch.awaiting_start = ch.resent = False
            return Actions({**item, "resumed": True} if resumed else item)
        if kind == "retargeted" and ch.retarget_frames is not None:
            ch.retarget_from = int(item.get("from_seq", 0))
        elif kind == "end":
            del self.characters[cid]
            return Actions({**item, "frames": ch.delivered})
        elif kind == "error":
            return self._error(ch, item)
        return Actions(item)

    def _frame(self, frame: Frame) -> Frame:
        ch = self.characters.get(frame.character) if frame.character is not None else None
        if ch is None:
            return frame
        if ch.retarget_frames is not None and ch.retarget_from is not None and frame.seq >= ch.retarget_from:
            ch.retarget_frames = ch.retarget_from = None  # the frame's remaining counts the retarget now
        seq = ch.base + frame.seq
        out = dataclasses.replace(frame, seq=seq, t=(seq + 1) / self.fps) if ch.base else frame
        ch.recent.append(out)
        ch.delivered = seq + 1
        ch.remaining = frame.remaining
        return out

    def _error(self, ch: _Character, item: Message) -> Actions:
        cid = item["character"]
        if item.get("code") == "validation_error" and ch.awaiting_start and ch.resent and "retargeted" in ch.last_start:
            # A replica older than the "retargeted" option (a rolling upgrade): the resume again, without it.
            ch.last_start = {k: v for k, v in ch.last_start.items() if k != "retargeted"}
            return Actions(None, send=[copy.deepcopy(ch.last_start)])
        if item.get("code") == "unknown_style":
            # A start refused during a resume is resent as the resume (received context, frames still to come).
            named = ch.last_start if ch.awaiting_start else ch.last_style
            sid = named.get("style_id") if named is not None else None
            body = self.styles.get(sid) if isinstance(sid, str) else None
            if named is not None and isinstance(sid, str) and body is not None:
                return Actions(None, register=(sid, body), send=[copy.deepcopy(named)])
        if ch.awaiting_start:
            del self.characters[cid]  # the start failed: nothing to resume
        return Actions(item)

    # ------------------------------------------------------------------ after a reconnection
    def resume_messages(self) -> list[Message]:
        """A ``start`` for every live character, from the frames it received last; cancelled ones are dropped."""
        out = []
        for cid, ch in list(self.characters.items()):
            if ch.cancelled:
                del self.characters[cid]
                continue
            remaining = ch.retarget_frames if ch.retarget_frames is not None else ch.remaining
            ch.retarget_frames = ch.retarget_from = None
            if ch.delivered and remaining <= 0:
                del self.characters[cid]  # every frame arrived; only the end was lost
                continue
            msg = dict(ch.start)
            if ch.delivered:
                msg["context"] = self._context(ch)
                msg["frames"] = remaining
                if ch.retargeted:  # mid-motion, so the new server finishes its facing as a retargeted one's
                    msg["retargeted"] = True
            ch.base, ch.remaining, ch.awaiting_start, ch.resent = ch.delivered, remaining, True, True
            ch.last_start = copy.deepcopy(msg)
            out.append(msg)
        if out:
            self.resumes += 1
        return out

    def _context(self, ch: _Character) -> dict[str, Any]:
        """The last ``context_frames`` poses the caller got: received frames, after the original context's
        last ones when fewer have arrived (or the first received one held, if that context cannot be read)."""
        roots = np.stack([f.root_position for f in ch.recent]).astype(np.float64)
        rots = np.stack([f.rotations for f in ch.recent]).astype(np.float64)
        need = self.context_frames - len(roots)
        if need > 0:
            before = self._arrays(ch.start["context"])
            if before is not None and len(before[0]) >= need:
                roots = np.concatenate([before[0][-need:], roots])
                rots = np.concatenate([before[1][-need:], rots])
            else:
                roots = np.concatenate([np.repeat(roots[:1], need, 0), roots])
                rots = np.concatenate([np.repeat(rots[:1], need, 0), rots])
        return {"root_positions": roots.tolist(), "rotations": rots.tolist()}

    def _arrays(self, motion: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
        """A context payload as (roots, rotations) in the model's joint order and fps, when that is plain."""
        names = [n.rsplit(":", 1)[-1].lower() for n in self.joint_names]
        try:
            if "bvh" in motion:
                text = str(motion["bvh"])
                if text.lstrip("\ufeff \t\r\n")[:9].upper() != "HIERARCHY":
                    return None  # BVH text only: never a path
                poses = load_bvh_poses(text, fps=self.fps)
                roots, rots, joints, fps = poses.root_positions, poses.rotations, poses.joints, self.fps
            else:
                roots, rots = np.asarray(motion["root_positions"]), np.asarray(motion["rotations"])
                joints, fps = motion.get("joints"), float(motion.get("fps") or self.fps)
        except (ValueError, KeyError, TypeError, OSError):
            return None
        if abs(fps - self.fps) > 1e-6 or rots.ndim != 3:
            return None
        if joints is not None:
            have = [str(n).rsplit(":", 1)[-1].lower() for n in joints]
            if sorted(have) != sorted(names):
                return None  # another rig: the server maps it, this client does not
            rots = rots[:, [have.index(n) for n in names]]
        if rots.shape[1] != len(names):
            return None
        return np.asarray(roots, dtype=np.float64).reshape(-1, 3), np.asarray(rots, dtype=np.float64)

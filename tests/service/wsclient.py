"""A small synchronous client of ``/v1/stream`` for the tests (what a game engine plugin would do)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
from websockets.sync.client import connect

from service.streaming.frames import floats_per_frame


def decode_binary(data: bytes, joints: int) -> dict:
    """One binary frame message (``service.streaming.frames.encode_binary``) as slot, seq, t, pose and remaining."""
    v = np.frombuffer(data, dtype="<f4")
    if v.size != floats_per_frame(joints):
        raise ValueError(f"expected {floats_per_frame(joints)} floats, got {v.size}")
    return {"slot": int(v[0]), "seq": int(v[1]), "t": float(v[2]), "root_position": v[3:6].copy(),
            "rotations": v[6 : 6 + 4 * joints].reshape(joints, 4).copy(), "remaining": int(v[-1])}


class Ws:
    def __init__(self, url: str, encoding: str = "json", query: str = "", **kw: Any) -> None:
        sep = "&" if query else ""
        self.conn = connect(f"{url}?encoding={encoding}{sep}{query}", proxy=None, compression=None,
                            open_timeout=20, **kw)
        self.encoding = encoding
        self.hello = self.json()
        assert self.hello["type"] == "hello", self.hello
        self.joints = len(self.hello["model"]["skeleton"]["joints"])
        self.slots: dict[int, str] = {}

    def __enter__(self) -> Ws:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.conn.close()

    def send(self, message: dict | str | bytes) -> None:
        self.conn.send(message if isinstance(message, (str, bytes)) else json.dumps(message))

    def recv(self, timeout: float = 30.0) -> dict:
        """The next message as a dict; binary frames are decoded (``type`` ``frame``, ``pose`` arrays)."""
        raw = self.conn.recv(timeout)
        if isinstance(raw, bytes):
            f = decode_binary(raw, self.joints)
            return {"type": "frame", "character": self.slots.get(f["slot"]), "slot": f["slot"], "seq": f["seq"],
                    "t": f["t"], "remaining": f["remaining"],
                    "pose": {"root_position": f["root_position"], "rotations": f["rotations"]}}
        msg = json.loads(raw)
        if msg.get("type") == "started":
            self.slots[msg["slot"]] = msg["character"]
        return msg

    json = recv

    def messages_until(self, stop: threading.Event, poll_s: float = 1.0) -> Iterator[dict]:
        """Each message as it arrives, until ``stop`` is set or the connection ends (for a reading thread, which
        then keeps what it has)."""
        while not stop.is_set():
            try:
                m = self.recv(timeout=poll_s)
            except TimeoutError:
                continue
            except Exception:  # the connection ended
                return
            yield m

    def ping(self, ident: Any = "p", timeout: float = 30.0) -> list[dict]:
        """Send a ping and read until its pong; returns what came before it."""
        self.send({"type": "ping", "id": ident})
        seen: list[dict] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv(timeout)
            if m["type"] == "pong" and m.get("id") == ident:
                return seen
            seen.append(m)
        raise TimeoutError("no pong")

    def run(self, characters: set[str], timeout: float = 60.0, on_frame=None) -> dict[str, dict]:
        """Read until every character in ``characters`` has ended; frames, end and other messages per character."""
        out: dict[str, dict[str, Any]] = {c: {"frames": [], "end": None, "messages": []} for c in characters}
        deadline = time.monotonic() + timeout
        while any(v["end"] is None for v in out.values()):
            m = self.recv(max(0.1, deadline - time.monotonic()))
            c = m.get("character")
            if c not in out:
                if m["type"] == "error":
                    raise AssertionError(f"unexpected error: {m}")
                continue
            if m["type"] == "frame":
                out[c]["frames"].append(m)
                if on_frame is not None:
                    on_frame(self, m)
            elif m["type"] == "end":
                out[c]["end"] = m
            else:
                out[c]["messages"].append(m)
        return out


def start_message(character: str, frames: int, seed: int | None = 1, pace: str = "asap", **kw: Any) -> dict:
    from tests.service.conftest import bvh, context_clip, target_clip

    msg = {"type": "start", "character": character, "context": bvh(context_clip()), "target": bvh(target_clip()),
           "frames": frames, "seed": seed, "pace": pace}
    msg.update(kw)
    return msg


def poses_of(frames: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """``(roots [N, 3], rotations [N, J, 4])`` as float32 arrays."""
    roots = np.array([f["pose"]["root_position"] for f in frames], dtype=np.float32)
    rots = np.array([f["pose"]["rotations"] for f in frames], dtype=np.float32)
    return roots, rots

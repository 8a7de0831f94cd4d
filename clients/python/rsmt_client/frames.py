"""Streamed frames: :class:`Frame`, and how to read one from a binary message (:class:`FrameLayout`, the layout
``hello.frame_layout`` declares, never a hard-coded one) or from a JSON ``frame`` message."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rsmt_client.errors import RsmtError

Message = dict[str, Any]


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

"""The stored form of a registered style clip: a small JSON header and the clip's float32 arrays as raw bytes.

Layout (no pickle, nothing executable)::

    b"RSMTSTY1" | uint32 LE header length | header (UTF-8 JSON) | rotations float32 LE [T, J, 4] | roots float32 LE [T, 3]

The header says ``style_id``, ``name``, ``fps``, ``frames``, ``joints`` (the model's joint names, in order)
and ``model``. The arrays are the clip as the model saw it (on its rig, at its fps), so encoding it again
on any replica gives the same content hash, the same ``style_id`` and the same code.

A style of several clips (``POST /v1/styles`` with ``motions``) is stored as one record with the magic
``b"RSMTSTY2"``: its header adds ``clips``, each clip's frames (they sum to ``frames``), and the arrays are the
clips' one after the other. A replica that reads only the first magic ignores such a record (bad magic)
instead of encoding the clips as one.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

MAGIC = b"RSMTSTY1"
MAGIC_SET = b"RSMTSTY2"
_LEN = struct.Struct("<I")
MAX_HEADER_BYTES = 1 << 20


class CodecError(ValueError):
    """Bytes that are not a stored style clip (wrong magic, truncated, inconsistent sizes)."""


@dataclass(frozen=True)
class StoredClip:
    """A registered clip as stored: its id, name, rate, joint names and arrays (float32)."""

    style_id: str
    name: str
    fps: float
    joints: tuple[str, ...]
    model: str
    rotations: np.ndarray  # [T, J, 4] local x, y, z, w (of several clips: theirs, one after the other)
    root_positions: np.ndarray  # [T, 3]
    clip_frames: tuple[int, ...] = ()  # each clip's frames, for a style of several; () for one clip

    @property
    def frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def clips(self) -> int:
        return max(1, len(self.clip_frames))

    def parts(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Each clip's ``(rotations, root_positions)``."""
        ends = np.cumsum(self.clip_frames or (self.frames,))
        starts = [0, *ends[:-1].tolist()]
        return [(self.rotations[a:b], self.root_positions[a:b]) for a, b in zip(starts, ends.tolist(), strict=True)]

    def meta(self) -> dict[str, Any]:
        """What listing a style needs, without the arrays."""
        meta: dict[str, Any] = {"style_id": self.style_id, "name": self.name, "frames": self.frames}
        if self.clips > 1:
            meta["clips"] = self.clips
        return meta


def encode_clip(clip: StoredClip) -> bytes:
    rot = np.ascontiguousarray(clip.rotations, dtype="<f4")
    root = np.ascontiguousarray(clip.root_positions, dtype="<f4")
    t, j = rot.shape[0], len(clip.joints)
    if rot.shape != (t, j, 4) or root.shape != (t, 3):
        raise CodecError(f"rotations {list(rot.shape)} and roots {list(root.shape)} do not fit {t} frames of {j} joints")
    head: dict[str, Any] = {"style_id": clip.style_id, "name": clip.name, "fps": float(clip.fps), "frames": t,
                            "joints": list(clip.joints), "model": clip.model}
    several = len(clip.clip_frames) > 1
    if several:
        if sum(clip.clip_frames) != t or min(clip.clip_frames) < 1:
            raise CodecError(f"clip lengths {list(clip.clip_frames)} do not add up to {t} frames")
        head["clips"] = [int(n) for n in clip.clip_frames]
    header = json.dumps(head, separators=(",", ":")).encode()
    return b"".join((MAGIC_SET if several else MAGIC, _LEN.pack(len(header)), header, rot.tobytes(), root.tobytes()))


def decode_clip(data: bytes) -> StoredClip:
    several = data.startswith(MAGIC_SET)
    if not (several or data.startswith(MAGIC)) or len(data) < len(MAGIC) + _LEN.size:
        raise CodecError("not a stored style clip (bad magic)")
    (size,) = _LEN.unpack_from(data, len(MAGIC))
    start = len(MAGIC) + _LEN.size
    if size > MAX_HEADER_BYTES or start + size > len(data):
        raise CodecError("stored style clip header is truncated or too large")
    try:
        head = json.loads(data[start:start + size])
        t, joints = int(head["frames"]), tuple(str(n) for n in head["joints"])
        style_id, name, fps, model = str(head["style_id"]), str(head["name"]), float(head["fps"]), str(head["model"])
        clip_frames = tuple(int(n) for n in head["clips"]) if several else ()
    except (ValueError, KeyError, TypeError) as exc:
        raise CodecError(f"stored style clip header is not valid: {exc}") from exc
    if several and (len(clip_frames) < 2 or min(clip_frames) < 1 or sum(clip_frames) != t):
        raise CodecError(f"stored style's clip lengths {list(clip_frames)} do not add up to its {t} frames")
    body = memoryview(data)[start + size:]
    n_rot, n_root = t * len(joints) * 4, t * 3
    if t < 1 or not joints or len(body) != 4 * (n_rot + n_root):
        raise CodecError(f"stored style clip holds {len(body)} bytes of arrays; {t} frames of {len(joints)} joints "
                         f"need {4 * (n_rot + n_root)}")
    arrays = np.frombuffer(body, dtype="<f4")
    rot = arrays[:n_rot].reshape(t, len(joints), 4).astype(np.float32)
    root = arrays[n_rot:].reshape(t, 3).astype(np.float32)
    return StoredClip(style_id, name, fps, joints, model, rot, root, clip_frames)

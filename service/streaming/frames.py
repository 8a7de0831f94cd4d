"""Streamed frame messages: the binary float32 layout the hello message declares, and the JSON form.

Both forms carry the same float32 numbers: JSON writes each float32 with the shortest text that
reads back to it, so a client decoding either gets identical poses.
"""

from __future__ import annotations

import numpy as np
import orjson

FLOATS_BEFORE_ROTATIONS = 6  # slot, seq, t, root x, y, z


def floats_per_frame(joints: int) -> int:
    return FLOATS_BEFORE_ROTATIONS + 4 * joints + 1


def frame_layout(joints: int) -> dict:
    """``hello.frame_layout`` for a model with ``joints`` joints (docs/protocol.md, Binary frames)."""
    rot = 4 * joints
    return {
        "encoding": "float32-le",
        "floats_per_frame": floats_per_frame(joints),
        "fields": [
            {"name": "slot", "offset": 0, "count": 1},
            {"name": "seq", "offset": 1, "count": 1},
            {"name": "t", "offset": 2, "count": 1},
            {"name": "root_position", "offset": 3, "count": 3},
            {"name": "rotations", "offset": 6, "count": rot},
            {"name": "remaining", "offset": 6 + rot, "count": 1},
        ],
    }


def encode_binary(slots: np.ndarray, seqs: np.ndarray, t: np.ndarray, roots: np.ndarray, rotations: np.ndarray,
                  remaining: np.ndarray) -> list[bytes]:
    """One little-endian float32 message per row; inputs are ``[N]``, ``[N, 3]`` and ``[N, J, 4]``."""
    n, j = rotations.shape[0], rotations.shape[1]
    out = np.empty((n, floats_per_frame(j)), dtype="<f4")
    out[:, 0], out[:, 1], out[:, 2] = slots, seqs, t
    out[:, 3:6] = roots
    out[:, 6 : 6 + 4 * j] = rotations.reshape(n, 4 * j)
    out[:, -1] = remaining
    return [row.tobytes() for row in out]


def encode_json(character: str, slot: int, seq: int, t: float, remaining: int, root: np.ndarray,
                rotations: np.ndarray) -> str:
    """The ``frame`` text message of one character."""
    return orjson.dumps(
        {"type": "frame", "character": character, "slot": slot, "seq": seq, "t": t, "remaining": remaining,
         "pose": {"root_position": root, "rotations": rotations}},
        option=orjson.OPT_SERIALIZE_NUMPY,
    ).decode()

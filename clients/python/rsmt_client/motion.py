"""Motion payloads in (BVH files, arrays, clips) and poses out (numpy arrays, BVH).

A payload is what the contract calls a ``Motion``: ``{"bvh": text}`` or ``{"root_positions",
"rotations"[, "joints", "fps"]}``. :func:`motion_payload` builds one from whatever is at hand.
Results are :class:`Poses`: float32 arrays in the model's units and axes (see ``GET /v1/model``).

BVH reading and writing use :mod:`model.motion.bvh`, imported only when needed (it brings torch).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


def read_bvh(path: str | Path) -> str:
    """The text of a BVH file, checked locally first (errors name the file and line)."""
    from model.motion.bvh import BvhDocument

    path = Path(path)
    text = path.read_text(encoding="utf-8-sig")
    BvhDocument.parse(text, source=str(path))
    return text


def motion_payload(motion: Any) -> dict[str, Any]:
    """A contract ``Motion`` from:

    - a dict already in payload form (passed through),
    - BVH text (starts with ``HIERARCHY``) or a path to a ``.bvh`` file,
    - :class:`Poses`, a ``model.motion.clip.Clip``, or a ``(root_positions [T,3], rotations [T,J,4])`` pair.
    """
    if isinstance(motion, Mapping):
        return dict(motion)
    if isinstance(motion, Poses):
        return motion.to_payload()
    if isinstance(motion, Path):
        return {"bvh": read_bvh(motion)}
    if isinstance(motion, str):
        if motion.lstrip("\ufeff \t\r\n")[:9].upper() == "HIERARCHY":
            return {"bvh": motion}
        return {"bvh": read_bvh(motion)}
    if isinstance(motion, tuple) and len(motion) == 2:
        roots, rots = (np.asarray(a, dtype=np.float64) for a in motion)
        return {"root_positions": roots.tolist(), "rotations": rots.tolist()}
    if type(motion).__name__ == "Clip" and hasattr(motion, "skeleton"):
        from model.motion.bvh_clip import dump_clip

        return {"bvh": dump_clip(motion)}
    raise TypeError(f"cannot make a Motion payload from {type(motion).__name__}: give BVH text or a path, "
                    "a payload dict, Poses, a Clip or (root_positions, rotations)")


@dataclass
class Poses:
    """Frames of one character: ``root_positions [N, 3]`` and local ``rotations [N, J, 4]`` (x, y, z, w), float32.

    Units and axes are the model's (``GET /v1/model`` ``skeleton``: cm, Y up, right-handed for the
    shipped models); joints are in the order of ``skeleton.joints``.
    """

    root_positions: np.ndarray
    rotations: np.ndarray
    fps: float
    joints: tuple[str, ...] | None = None
    style_id: str | None = None
    model: str | None = None
    timing_ms: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.root_positions = np.asarray(self.root_positions, dtype=np.float32).reshape(-1, 3)
        rot = np.asarray(self.rotations, dtype=np.float32)
        self.rotations = rot.reshape(self.root_positions.shape[0], -1, 4) if rot.size else rot.reshape(0, 0, 4)

    @property
    def num_frames(self) -> int:
        return int(self.root_positions.shape[0])

    def __len__(self) -> int:
        return self.num_frames

    @classmethod
    def from_frames(cls, frames: Sequence[Mapping[str, Any]], fps: float, **kw: Any) -> Poses:
        """From the contract's ``[{"root_position", "rotations"}, ...]``."""
        roots = np.array([f["root_position"] for f in frames], dtype=np.float32).reshape(-1, 3)
        rots = np.array([f["rotations"] for f in frames], dtype=np.float32)
        return cls(roots, rots, fps, **kw)

    def to_payload(self) -> dict[str, Any]:
        """These frames as a ``Motion`` payload (e.g. to chain one transition into the next)."""
        out: dict[str, Any] = {"root_positions": self.root_positions.tolist(), "rotations": self.rotations.tolist(),
                               "fps": self.fps}
        if self.joints is not None:
            out["joints"] = list(self.joints)
        return out

    def to_bvh(self, model_info: Mapping[str, Any], rotation_order: str = "ZXY", precision: int | None = 6) -> str:
        """BVH text of these frames on the model's skeleton (``GET /v1/model``)."""
        return poses_to_bvh(model_info, self.root_positions, self.rotations, self.fps, rotation_order, precision)

    def save_bvh(self, path: str | Path, model_info: Mapping[str, Any], rotation_order: str = "ZXY") -> Path:
        path = Path(path)
        path.write_text(self.to_bvh(model_info, rotation_order), encoding="utf-8")
        return path


def poses_to_bvh(model_info: Mapping[str, Any], root_positions: np.ndarray, rotations: np.ndarray, fps: float,
                 rotation_order: str = "ZXY", precision: int | None = 6) -> str:
    """BVH text: the skeleton of ``model_info`` (joints with parent and offset), root with position channels.

    Works for any rig the server serves (no skeleton profile needed); leaves get a zero End Site.
    """
    import torch

    from model.motion.bvh import BvhDocument, BvhJoint
    from model.motion.rotations import DEG, quat_normalize, quat_to_euler

    joints = model_info["skeleton"]["joints"]
    order = rotation_order.upper()
    if sorted(order) != ["X", "Y", "Z"]:
        raise ValueError(f"rotation order {rotation_order!r} must use X, Y and Z once each")
    rots = np.asarray(rotations, dtype=np.float64)
    roots = np.asarray(root_positions, dtype=np.float64).reshape(-1, 3)
    if rots.ndim != 3 or rots.shape[1:] != (len(joints), 4) or rots.shape[0] != roots.shape[0]:
        raise ValueError(f"expected rotations [{roots.shape[0]}, {len(joints)}, 4], got {list(rots.shape)}")
    has_child = {j["parent"] for j in joints}
    bvh_joints = []
    columns = [roots]
    for i, j in enumerate(joints):
        chans = tuple(f"{a}rotation" for a in order)
        if i == 0:
            chans = ("Xposition", "Yposition", "Zposition") + chans
        offset = (0.0, 0.0, 0.0) if i == 0 else tuple(float(v) for v in j["offset"])
        bvh_joints.append(BvhJoint(j["name"], int(j["parent"]), offset, chans, None if i in has_child else (0.0, 0.0, 0.0)))
        q = quat_normalize(torch.from_numpy(np.ascontiguousarray(rots[:, i])))
        columns.append((quat_to_euler(q, order) * DEG).numpy())
    motion = np.concatenate(columns, axis=1) if roots.shape[0] else np.zeros((0, 3 + 3 * len(joints)))
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    return BvhDocument(bvh_joints, 1.0 / fps, motion).format(precision)


def load_bvh_poses(source: str | Path, fps: float | None = None) -> Poses:
    """A BVH file (or text) as :class:`Poses` on its own rig (``load_clip``), resampled to ``fps`` if given."""
    from model.motion.bvh_clip import load_clip

    clip = load_clip(source if isinstance(source, str) else Path(source), fps=fps)
    return Poses(clip.root_positions.numpy(), clip.rotations.numpy(), float(clip.fps), joints=tuple(clip.skeleton.names))

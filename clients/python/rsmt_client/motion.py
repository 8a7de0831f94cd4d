"""Motion payloads in (BVH files, arrays, clips) and poses out (numpy arrays, BVH).

A payload is what the contract calls a ``Motion``: ``{"bvh": text}`` or ``{"root_positions",
"rotations"[, "joints", "fps"]}``. :func:`motion_payload` builds one from whatever is at hand.
Results are :class:`Poses`: float32 arrays in the model's units and axes (see ``GET /v1/model``).
BVH files are read and written by :mod:`rsmt_client.bvh` (numpy only).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rsmt_client.bvh import POSITION_CHANNELS, BvhFile, BvhJoint, read_text
from rsmt_client.quaternions import (
    check_order,
    euler_to_quat,
    make_continuous,
    quat_normalize,
    quat_slerp,
    quat_to_euler,
)
from rsmt_client.reach import Reach


def read_bvh(path: str | Path) -> str:
    """The text of a BVH file, checked locally first (a :class:`rsmt_client.bvh.BvhError` names the file and line)."""
    text = read_text(path)
    BvhFile.parse(text, source=str(path))
    return text


def _is_bvh_text(text: str) -> bool:
    return text.lstrip("\ufeff \t\r\n")[:9].upper() == "HIERARCHY"


def _is_clip(motion: Any) -> bool:
    """Duck typing for ``model.motion.clip.Clip`` (the client does not import the model)."""
    skeleton = getattr(motion, "skeleton", None)
    return all(hasattr(skeleton, a) for a in ("names", "parents", "offsets")) and all(
        hasattr(motion, a) for a in ("rotations", "root_positions", "fps"))


def motion_payload(motion: Any) -> dict[str, Any]:
    """A contract ``Motion`` from:

    - a dict already in payload form (passed through),
    - BVH text (starts with ``HIERARCHY``) or a path to a ``.bvh`` file,
    - :class:`Poses`, a ``(root_positions [T,3], rotations [T,J,4])`` pair, or a clip: any object with
      ``skeleton`` (``names``, ``parents``, ``offsets``), ``rotations``, ``root_positions`` and ``fps``
      such as ``model.motion.clip.Clip`` (sent as BVH on its own skeleton).
    """
    if isinstance(motion, Mapping):
        return dict(motion)
    if isinstance(motion, Poses):
        return motion.to_payload()
    if isinstance(motion, Path):
        return {"bvh": read_bvh(motion)}
    if isinstance(motion, str):
        return {"bvh": motion if _is_bvh_text(motion) else read_bvh(motion)}
    if isinstance(motion, tuple) and len(motion) == 2:
        roots, rots = (np.asarray(a, dtype=np.float64) for a in motion)
        return {"root_positions": roots.tolist(), "rotations": rots.tolist()}
    if _is_clip(motion):
        return {"bvh": clip_to_bvh(motion)}
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
    reach: Reach | None = None  # whether the target was within reach (rsmt_client.reach; None: not said)

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


def _bvh_of(names: Sequence[str], parents: Sequence[int], offsets: Sequence[Sequence[float]],
            end_sites: Mapping[int, Sequence[float]], root_positions: Any, rotations: Any, fps: float,
            rotation_order: str) -> BvhFile:
    """A BVH file of poses: the root with position channels, every joint three rotation channels in ``rotation_order``."""
    order = check_order(rotation_order)
    rots = np.asarray(rotations, dtype=np.float64)
    roots = np.asarray(root_positions, dtype=np.float64).reshape(-1, 3)
    if rots.ndim != 3 or rots.shape[1:] != (len(names), 4) or rots.shape[0] != roots.shape[0]:
        raise ValueError(f"expected rotations [{roots.shape[0]}, {len(names)}, 4], got {list(rots.shape)}")
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    has_child = set(parents)
    joints = []
    for i, name in enumerate(names):
        channels = tuple(f"{a}rotation" for a in order)
        if i == 0:
            channels = POSITION_CHANNELS + channels
        end = end_sites.get(i, (0.0, 0.0, 0.0) if i not in has_child else None)
        offset = (0.0, 0.0, 0.0) if i == 0 else offsets[i]
        joints.append(BvhJoint(str(name), int(parents[i]), _vec3(offset), channels, None if end is None else _vec3(end)))
    euler = quat_to_euler(rots, order).reshape(roots.shape[0], -1) if roots.shape[0] else np.zeros((0, 3 * len(names)))
    return BvhFile(joints, 1.0 / fps, np.concatenate([roots, euler], axis=1))


def _vec3(values: Sequence[float]) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


def poses_to_bvh(model_info: Mapping[str, Any], root_positions: np.ndarray, rotations: np.ndarray, fps: float,
                 rotation_order: str = "ZXY", precision: int | None = 6) -> str:
    """BVH text: the skeleton of ``model_info`` (joints with parent and offset), root with position channels.

    Works for any rig the server serves (no skeleton profile needed); leaves get a zero End Site.
    """
    joints = model_info["skeleton"]["joints"]
    names = [j["name"] for j in joints]
    parents = [int(j["parent"]) for j in joints]
    offsets = [j.get("offset", (0.0, 0.0, 0.0)) for j in joints]
    return _bvh_of(names, parents, offsets, {}, root_positions, rotations, fps, rotation_order).format(precision)


def clip_to_bvh(clip: Any, rotation_order: str = "ZXY", precision: int | None = 6) -> str:
    """BVH text of a clip-like object (see :func:`motion_payload`), End Sites from ``skeleton.end_sites`` if it has them."""
    sk = clip.skeleton
    ends = {int(j): end for j, end in getattr(sk, "end_sites", ())}
    return _bvh_of(list(sk.names), list(sk.parents), list(sk.offsets), ends, np.asarray(clip.root_positions),
                   np.asarray(clip.rotations), float(clip.fps), rotation_order).format(precision)


def load_bvh_poses(source: str | Path, fps: float | None = None) -> Poses:
    """A BVH file (a path, or text starting with ``HIERARCHY``) as :class:`Poses` on the file's own rig.

    Every joint of the file, in file order; the root position is the root joint's OFFSET with its
    position channels in place; rotations are the intrinsic Euler channels of each joint, composed
    in file order (degrees), as x, y, z, w quaternions with signs continuous over time. With ``fps``
    the frames are resampled (rotations slerped, the root interpolated linearly; the first frame
    is kept, the last is the last sample time inside the clip).
    """
    if isinstance(source, str) and _is_bvh_text(source):
        bvh = BvhFile.parse(source)
    else:
        bvh = BvhFile.read(source)
    quats = np.empty((bvh.num_frames, len(bvh.joints), 4))
    for j in range(len(bvh.joints)):
        axes, degrees = bvh.rotation_degrees(j)
        quats[:, j] = euler_to_quat(degrees, axes)
    roots = bvh.translations(0)
    rots = make_continuous(quat_normalize(quats)) if bvh.num_frames else quats
    if fps is not None and bvh.num_frames and abs(fps - bvh.fps) > 1e-9:
        roots, rots = _resample(roots, rots, bvh.fps / fps)
    return Poses(roots, rots, float(fps or bvh.fps), joints=bvh.names)


def _resample(roots: np.ndarray, rots: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Samples every ``step`` source frames from frame 0 while inside the clip."""
    if not (math.isfinite(step) and step > 0):
        raise ValueError("fps must be a positive number")
    frames = roots.shape[0]
    times = np.arange(int((frames - 1) / step + 1e-9) + 1) * step
    i0 = np.minimum(np.floor(times).astype(int), frames - 1)
    i1 = np.minimum(i0 + 1, frames - 1)
    frac = (times - i0)[:, None]
    roots = roots[i0] + (roots[i1] - roots[i0]) * frac
    return roots, quat_slerp(rots[i0], rots[i1], frac[:, :, None])

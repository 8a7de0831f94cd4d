"""BVH motion files as a faithful, torch-free document model: parse, check, format.

:class:`BvhDocument` keeps a file exactly as written (any single-root hierarchy, any channel set and
order per joint, End Sites, any frame time) so that ``parse -> format -> parse`` is lossless.
:mod:`model.motion.bvh_clip` interprets a document for the model and goes back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.motion.bvh_parser import (
    CHANNEL_NAMES,
    POSITION_CHANNELS,
    ROTATION_CHANNELS,
    BvhError,
    BvhJoint,
    Vec3,
    fps_from_frame_time,
    parse_bvh_parts,
)

__all__ = ["CHANNEL_NAMES", "POSITION_CHANNELS", "ROTATION_CHANNELS", "BvhDocument", "BvhError", "BvhJoint", "Vec3"]


@dataclass(eq=False)
class BvhDocument:
    """A BVH file as data.

    Attributes:
        joints: ROOT and JOINT blocks in file order (parents always come before their children).
        frame_time: seconds per frame, as written.
        motion: ``[frames, total_channels]`` float64 channel values as written (degrees for
            rotations), columns in joint order then each joint's channel order.
    """

    joints: list[BvhJoint]
    frame_time: float
    motion: np.ndarray

    def __post_init__(self) -> None:
        self.joints = list(self.joints)
        if not self.joints:
            raise ValueError("a BVH document needs at least one joint")
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ValueError(f"joint names must be unique; repeated: {', '.join(dup)}")
        if self.joints[0].parent != -1 or any(not 0 <= j.parent < i for i, j in enumerate(self.joints) if i):
            raise ValueError("joints must form one hierarchy in topological order: the root first, parents before children")
        self.frame_time = float(self.frame_time)
        if not (math.isfinite(self.frame_time) and self.frame_time > 0):
            raise ValueError(f"frame_time must be a positive number of seconds, got {self.frame_time}")
        motion = np.asarray(self.motion, dtype=np.float64)
        width = self.num_channels
        if motion.ndim == 1 and motion.size == 0:
            motion = motion.reshape(0, width)
        if motion.ndim != 2 or motion.shape[1] != width:
            raise ValueError(f"motion must be [frames, {width}] for these joints' channels, got {list(motion.shape)}")
        self.motion = motion

    # ------------------------------------------------------------------ structure
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def parents(self) -> tuple[int, ...]:
        return tuple(j.parent for j in self.joints)

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_channels(self) -> int:
        return sum(len(j.channels) for j in self.joints)

    @property
    def fps(self) -> float:
        """Frames per second, snapped to a whole number when the frame time is a rounded ``1/n``."""
        return fps_from_frame_time(self.frame_time)

    def channel_slices(self) -> list[slice]:
        """Per joint, the columns of :attr:`motion` that hold its channels."""
        out, start = [], 0
        for j in self.joints:
            out.append(slice(start, start + len(j.channels)))
            start += len(j.channels)
        return out

    def joint_index(self, name: str) -> int:
        for i, j in enumerate(self.joints):
            if j.name == name:
                return i
        raise KeyError(f"no joint named {name!r}")

    def children(self) -> list[list[int]]:
        kids: list[list[int]] = [[] for _ in self.joints]
        for i, j in enumerate(self.joints):
            if j.parent >= 0:
                kids[j.parent].append(i)
        return kids

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BvhDocument):
            return NotImplemented
        return (
            self.joints == other.joints
            and self.frame_time == other.frame_time
            and self.motion.shape == other.motion.shape
            and bool(np.array_equal(self.motion, other.motion))
        )

    # ------------------------------------------------------------------ reading
    @classmethod
    def parse(cls, text: str, source: str = "<string>") -> BvhDocument:
        """Parse BVH text; malformed input raises :class:`BvhError` naming the line and the problem."""
        return cls(*parse_bvh_parts(text, source))

    @classmethod
    def read(cls, path: str | Path) -> BvhDocument:
        path = Path(path)
        raw = path.read_bytes()
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:
            # Some exporters write joint names in a legacy code page; latin-1 never fails.
            text = raw.decode("latin-1")
        return cls.parse(text, source=str(path))

    # ------------------------------------------------------------------ writing
    def format(self, precision: int | None = 6) -> str:
        """BVH text: tab-indented hierarchy, then ``MOTION``, ``Frames:``, ``Frame Time:`` and the frames.

        Motion values get ``precision`` decimals (``None``: the shortest text that reads back
        exactly). OFFSETs and the frame time are always written exactly.
        """
        if not np.isfinite(self.motion).all():
            raise ValueError("motion holds NaN or infinite values, which BVH cannot store")
        kids = self.children()
        lines = ["HIERARCHY"]
        order: list[int] = []
        # Iterative pre-order walk: a writer must not hit the recursion limit on a deep chain.
        stack: list[tuple[int, int, bool]] = [(0, 0, False)]
        while stack:
            j, depth, closing = stack.pop()
            ind = "\t" * depth
            joint = self.joints[j]
            if closing:
                if joint.end_site is not None:
                    lines += [f"{ind}\tEnd Site", f"{ind}\t{{", f"{ind}\t\tOFFSET {_fmt3(joint.end_site)}", f"{ind}\t}}"]
                lines.append(f"{ind}}}")
                continue
            order.append(j)
            lines += [f"{ind}{'ROOT' if depth == 0 else 'JOINT'} {joint.name}", f"{ind}{{",
                      f"{ind}\tOFFSET {_fmt3(joint.offset)}"]
            lines.append(f"{ind}\tCHANNELS {len(joint.channels)}" + "".join(" " + c for c in joint.channels))
            stack.append((j, depth, True))
            stack.extend((k, depth + 1, False) for k in reversed(kids[j]))
        lines += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {_num(self.frame_time)}"]
        motion = self.motion
        if order != list(range(len(self.joints))):
            # Joints given in another topological order are written nested, so columns follow.
            slices = self.channel_slices()
            motion = motion[:, [c for j in order for c in range(slices[j].start, slices[j].stop)]]
        if precision is None:
            lines.extend(" ".join(map(repr, row)) for row in motion.tolist())
        else:
            row_fmt = " ".join([f"%.{int(precision)}f"] * motion.shape[1])
            lines.extend(row_fmt % tuple(row) for row in motion.tolist())
        return "\n".join(lines) + "\n"

    def write(self, path: str | Path, precision: int | None = 6) -> None:
        Path(path).write_text(self.format(precision), encoding="utf-8")


def _num(v: float) -> str:
    # repr is the shortest text that reads back to the same float.
    return repr(float(v))


def _fmt3(v: Vec3) -> str:
    return " ".join(_num(x) for x in v)

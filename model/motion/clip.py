"""A motion clip: local joint rotations and root positions over time on one skeleton.

Operations (``resample``, ``window``, ``mirror`` in :mod:`model.motion.mirror`) return new clips and
never change their input.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_make_continuous, quat_normalize, quat_slerp
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor


@dataclass(frozen=True)
class Clip:
    """Motion on a skeleton.

    Attributes:
        skeleton: the rig, with rest offsets in its units (cm for the shipped data).
        rotations: ``[T, J, 4]`` local (parent-relative) x,y,z,w quaternions.
        root_positions: ``[T, 3]`` world position of the root joint.
        fps: frames per second.
        name: where the clip came from (a file name, say), for messages.
    """

    skeleton: Skeleton
    rotations: Tensor
    root_positions: Tensor
    fps: float
    name: str = ""

    def __post_init__(self) -> None:
        t, j = self.rotations.shape[0], self.skeleton.num_joints
        if self.rotations.shape != (t, j, 4):
            raise ValueError(f"rotations must be [T, {j}, 4], got {list(self.rotations.shape)}")
        if self.root_positions.shape != (t, 3):
            raise ValueError(f"root_positions must be [{t}, 3], got {list(self.root_positions.shape)}")
        if self.fps <= 0:
            raise ValueError(f"fps must be positive, got {self.fps}")

    @property
    def num_frames(self) -> int:
        return int(self.rotations.shape[0])

    def to(self, dtype: torch.dtype) -> Clip:
        return replace(self, rotations=self.rotations.to(dtype), root_positions=self.root_positions.to(dtype))

    def global_transforms(self) -> tuple[Tensor, Tensor]:
        """World positions ``[T, J, 3]`` and rotations ``[T, J, 4]`` by forward kinematics."""
        return forward_kinematics(
            self.rotations, self.root_positions, self.skeleton.offsets_tensor(self.rotations.dtype), self.skeleton.parents
        )

    def global_positions(self) -> Tensor:
        return self.global_transforms()[0]

    def window(self, start: int, stop: int) -> Clip:
        """Frames ``[start, stop)`` as a new clip."""
        if not 0 <= start < stop <= self.num_frames:
            raise ValueError(f"window [{start}, {stop}) is outside the clip's {self.num_frames} frames")
        return replace(self, rotations=self.rotations[start:stop], root_positions=self.root_positions[start:stop])

    def resample(self, fps: float) -> Clip:
        """Resample to ``fps``: slerp rotations and lerp the root between neighbouring frames.

        The first frame is kept; the last output frame is the last sample time inside the clip.
        """
        if abs(fps - self.fps) < 1e-9:
            return self
        return self.retime(self.fps / fps, fps=fps)

    def retime(self, step: float, fps: float | None = None) -> Clip:
        """Sample the clip every ``step`` source frames (``step < 1`` slows it down).

        Used both to change fps and for temporal-rescale augmentation (same fps, new speed).
        """
        if step <= 0:
            raise ValueError("step must be positive")
        n = int((self.num_frames - 1) / step + 1e-9) + 1
        times = torch.arange(n, dtype=torch.float64) * step
        i0 = times.floor().long().clamp(max=self.num_frames - 1)
        i1 = (i0 + 1).clamp(max=self.num_frames - 1)
        frac = (times - i0).to(self.rotations.dtype)
        rots = quat_make_continuous(self.rotations, dim=0)
        rot = quat_slerp(rots[i0], rots[i1], frac[:, None])
        pos = torch.lerp(self.root_positions[i0], self.root_positions[i1], frac[:, None])
        return replace(self, rotations=quat_normalize(rot), root_positions=pos, fps=fps or self.fps)

"""The per-frame pose state the networks read and write, and the step that integrates a change.

A state frame holds, for every joint, in one canonical frame per transition (see
:class:`model.motion.features.CanonicalFrame`):

* ``rel``: position relative to the root's ground point ``(x_root, 0, z_root)`` (cm): horizontal
  offsets from the root, absolute heights, so feet know where the floor is while the features stay
  invariant to where the character stands;
* ``vel``: ``p[t] - p[t-1]`` (cm/frame), the root's included, so the state knows how it moves;
* ``rot``: global rotation in 6D.

The state vector is ``[rel (J*3), vel (J*3), rot (J*6)]``. The root's world ground position is
carried beside it (``root_xz``) and advanced by the root's velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.motion.rotations import sixd_normalize

Tensor = torch.Tensor
# What indexes a batch of frames: rows, a slice, a mask or index tensor, or one of each per leading dimension.
TensorIndex = int | slice | Tensor | tuple[int | slice | Tensor, ...]


@dataclass(frozen=True)
class PoseState:
    """A batch of pose frames ``[..., J, *]`` plus the root's ground position ``[..., 2]``."""

    rel: Tensor  # [..., J, 3]
    vel: Tensor  # [..., J, 3]
    rot: Tensor  # [..., J, 6]
    root_xz: Tensor  # [..., 2]

    @property
    def num_joints(self) -> int:
        return int(self.rel.shape[-2])

    def vector(self) -> Tensor:
        """Flatten to ``[..., J * 12]`` for the networks."""
        return torch.cat([self.rel.flatten(-2), self.vel.flatten(-2), self.rot.flatten(-2)], dim=-1)

    def positions(self) -> Tensor:
        """Positions in the canonical frame ``[..., J, 3]``."""
        ground = torch.stack(
            [self.root_xz[..., 0], torch.zeros_like(self.root_xz[..., 0]), self.root_xz[..., 1]], dim=-1
        )
        return self.rel + ground.unsqueeze(-2)

    def index(self, idx: TensorIndex) -> PoseState:
        return PoseState(self.rel[idx], self.vel[idx], self.rot[idx], self.root_xz[idx])

    def contiguous(self) -> PoseState:
        """The same states in contiguous memory (views of windows of any length get one layout)."""
        return PoseState(*(getattr(self, name).contiguous() for name in _FIELDS))

    @staticmethod
    def cat(items: list[PoseState], dim: int = 0) -> PoseState:
        """Join states along an existing batch or time axis ``dim`` (counted before the joint axis)."""
        return PoseState(*(torch.cat([getattr(p, name) for p in items], dim) for name in _FIELDS))

    @staticmethod
    def stack(items: list[PoseState], dim: int) -> PoseState:
        """Stack states along a new axis ``dim`` (counted before the joint axis), e.g. frames into ``[B, T, J, *]``."""
        return PoseState(*(torch.stack([getattr(p, name) for p in items], dim) for name in _FIELDS))


_FIELDS = ("rel", "vel", "rot", "root_xz")

# Ground coordinates (x, z) to a vector (x, 0, z) by one product, ``xz @ GROUND_TO_3D``: on the per-frame path at
# batch 1 (bound by per-operation dispatch) it replaces picking, zeroing and stacking; products by 0 and 1 add no
# rounding.
GROUND_TO_3D = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def state_dim(num_joints: int) -> int:
    return num_joints * 12


def state_from_positions(positions: Tensor, rotations_6d: Tensor, root: int = 0) -> PoseState:
    """States of a motion ``positions [..., T, J, 3]`` and ``rotations_6d [..., T, J, 6]``.

    Velocities are backward differences (frame 0 repeats frame 1).
    """
    vel = positions[..., 1:, :, :] - positions[..., :-1, :, :]
    vel = torch.cat([vel[..., :1, :, :], vel], dim=-3)
    root_xz = positions[..., root, ::2].clone()  # x, z; a copy, not a view of the caller's positions
    ground = torch.stack([root_xz[..., 0], torch.zeros_like(root_xz[..., 0]), root_xz[..., 1]], dim=-1)
    return PoseState(positions - ground.unsqueeze(-2), vel, rotations_6d, root_xz)


def integrate(state: PoseState, velocity: Tensor, rotation_delta: Tensor, root: int = 0,
              root_rotation: Tensor | None = None) -> PoseState:
    """The next frame: joints move by ``velocity [..., J, 3]``; rotations change by a 6D delta, except the
    root's where ``root_rotation [..., 6]`` imposes it.

    Rotations are re-orthonormalised every step (the paper adds 6D deltas and lets them drift off
    the rotation manifold until a post-process; we never leave it), the imposed root's with the others
    (one pass for all joints: the per-frame path is bound by per-operation dispatch at batch 1).
    """
    pos = state.positions() + velocity
    rot = state.rot + rotation_delta
    if root_rotation is not None:
        rot = torch.cat([rot[..., :root, :], root_rotation.unsqueeze(-2), rot[..., root + 1 :, :]], dim=-2)
    rot = sixd_normalize(rot)
    root_xz = pos[..., root, ::2]  # x, z (a view of pos, which nothing else holds)
    ground = torch.stack([root_xz[..., 0], torch.zeros_like(root_xz[..., 0]), root_xz[..., 1]], dim=-1)
    return PoseState(pos - ground.unsqueeze(-2), velocity, rot, root_xz)

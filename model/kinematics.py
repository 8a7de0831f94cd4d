"""Forward kinematics (local to global) and its inverse (global to local), batched, in torch.

A hierarchy is a ``parents`` sequence with ``parents[0] == -1`` and ``parents[j] < j`` (every
:class:`model.skeleton.Skeleton` is stored in that order). Rotations are x,y,z,w quaternions.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.rotations import quat_conjugate, quat_mul, quat_rotate

Tensor = torch.Tensor


def check_parents(parents: Sequence[int]) -> None:
    """Raise ``ValueError`` unless ``parents`` is a single-root, topologically ordered hierarchy."""
    if len(parents) == 0 or parents[0] != -1:
        raise ValueError("the first joint must be the root (parent -1)")
    for j, p in enumerate(parents[1:], start=1):
        if not 0 <= p < j:
            raise ValueError(f"joint {j} has parent {p}; parents must come before their children")


def forward_kinematics(
    local_rotations: Tensor,
    root_positions: Tensor,
    offsets: Tensor,
    parents: Sequence[int],
) -> tuple[Tensor, Tensor]:
    """Global joint positions and rotations from local rotations.

    Args:
        local_rotations: ``[..., J, 4]`` parent-relative rotations.
        root_positions: ``[..., 3]`` position of joint 0.
        offsets: ``[J, 3]`` or ``[..., J, 3]`` translation of each joint in its parent's frame
            (row 0 is ignored: the root is placed at ``root_positions``).
        parents: parent index per joint.

    Returns:
        ``(positions [..., J, 3], rotations [..., J, 4])`` in the world frame.
    """
    offsets = offsets.to(local_rotations.dtype).expand(*local_rotations.shape[:-1], 3)
    rots: list[Tensor] = [local_rotations[..., 0, :]]
    pos: list[Tensor] = [root_positions]
    for j in range(1, len(parents)):
        p = parents[j]
        pos.append(pos[p] + quat_rotate(rots[p], offsets[..., j, :]))
        rots.append(quat_mul(rots[p], local_rotations[..., j, :]))
    return torch.stack(pos, dim=-2), torch.stack(rots, dim=-2)


def global_to_local_rotations(global_rotations: Tensor, parents: Sequence[int]) -> Tensor:
    """Parent-relative rotations ``q_local[j] = q_global[parent]^-1 * q_global[j]`` ``[..., J, 4]``."""
    idx = torch.tensor([max(p, 0) for p in parents], device=global_rotations.device)
    parent_rot = global_rotations.index_select(-2, idx)
    local = quat_mul(quat_conjugate(parent_rot), global_rotations)
    return torch.cat([global_rotations[..., :1, :], local[..., 1:, :]], dim=-2)


def inverse_kinematics(
    global_positions: Tensor, global_rotations: Tensor, parents: Sequence[int]
) -> tuple[Tensor, Tensor]:
    """Invert :func:`forward_kinematics`: ``(local_rotations [..., J, 4], root_positions [..., 3])``.

    The bone offsets are the skeleton's, so only the root position is read from
    ``global_positions``; use :func:`bone_offsets_from_positions` to recover offsets.
    """
    return global_to_local_rotations(global_rotations, parents), global_positions[..., 0, :]


def bone_offsets_from_positions(
    global_positions: Tensor, global_rotations: Tensor, parents: Sequence[int]
) -> Tensor:
    """Per-frame offsets ``[..., J, 3]`` in each parent's frame that reproduce the positions."""
    idx = torch.tensor([max(p, 0) for p in parents], device=global_positions.device)
    delta = global_positions - global_positions.index_select(-2, idx)
    offsets = quat_rotate(quat_conjugate(global_rotations.index_select(-2, idx)), delta)
    return torch.cat([torch.zeros_like(offsets[..., :1, :]), offsets[..., 1:, :]], dim=-2)

"""Forward kinematics (local to global) and its inverse (global to local), batched, in torch.

A hierarchy is a ``parents`` sequence with ``parents[0] == -1`` and ``parents[j] < j`` (every
:class:`model.motion.skeleton.Skeleton` is stored in that order). Rotations are x,y,z,w quaternions.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.motion.rotations import quat_conjugate, quat_mul, quat_rotate

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
    # A list index rather than a tensor made here: traced (model.inference.traced_step), it stays a constant quietly.
    parent_rot = global_rotations[..., [max(p, 0) for p in parents], :]
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


def two_bone_ik(
    root_pos: Tensor, mid_pos: Tensor, end_pos: Tensor, root_rot: Tensor, mid_rot: Tensor, target: Tensor, eps: float = 1e-4
) -> tuple[Tensor, Tensor]:
    """Analytic two-bone IK (hip-knee-ankle): new world rotations of the root and middle joints.

    The chain bends in its current plane and then turns about the root so the end reaches
    ``target``; unreachable targets are approached as far as the bone lengths allow.

    Args:
        root_pos, mid_pos, end_pos: ``[..., 3]`` world positions of the three joints.
        root_rot, mid_rot: ``[..., 4]`` world rotations of the first two.
        target: ``[..., 3]`` where the end joint should go.

    Returns:
        ``(root_rot', mid_rot')`` world rotations; the end joint's world rotation is unchanged
        if the caller keeps it (recompute its local rotation from ``mid_rot'``).
    """
    from model.motion.rotations import axis_angle_to_quat, quat_mul  # local import keeps the module header small

    def unit(v: Tensor) -> Tensor:
        return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-8)

    def angle(u: Tensor, v: Tensor) -> Tensor:
        return torch.acos((unit(u) * unit(v)).sum(-1).clamp(-1.0, 1.0))

    l1 = (mid_pos - root_pos).norm(dim=-1)
    l2 = (end_pos - mid_pos).norm(dim=-1)
    d = (target - root_pos).norm(dim=-1).clamp((l1 - l2).abs() + eps, l1 + l2 - eps)
    ac_ab_0 = angle(end_pos - root_pos, mid_pos - root_pos)
    ba_bc_0 = angle(root_pos - mid_pos, end_pos - mid_pos)
    ac_at_0 = angle(end_pos - root_pos, target - root_pos)
    ac_ab_1 = torch.acos(((l2 * l2 - l1 * l1 - d * d) / (-2 * l1 * d)).clamp(-1.0, 1.0))
    ba_bc_1 = torch.acos(((d * d - l1 * l1 - l2 * l2) / (-2 * l1 * l2)).clamp(-1.0, 1.0))
    bend_axis = unit(torch.linalg.cross(end_pos - root_pos, mid_pos - root_pos))
    turn_axis = unit(torch.linalg.cross(end_pos - root_pos, target - root_pos))
    r0 = axis_angle_to_quat(bend_axis, ac_ab_1 - ac_ab_0)
    r1 = axis_angle_to_quat(bend_axis, ba_bc_1 - ba_bc_0)
    r2 = axis_angle_to_quat(turn_axis, ac_at_0)
    # A straight chain has no bend plane; it needs no bend either, so drop the NaN-free zero axis.
    turn = quat_mul(r2, r0)
    return quat_mul(turn, root_rot), quat_mul(turn, quat_mul(r1, mid_rot))

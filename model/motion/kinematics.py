"""Forward kinematics (local to global) and its inverse (global to local), batched, in torch.

A hierarchy is a ``parents`` sequence with ``parents[0] == -1`` and ``parents[j] < j`` (every
:class:`model.motion.skeleton.Skeleton` is stored in that order). Rotations are x,y,z,w quaternions.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.motion.rotations import quat_conjugate, quat_mul, quat_rotate
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor


def constant_index(values: Sequence[int], device: torch.device) -> Tensor:
    """An index tensor of ``values`` on ``device``, made once and kept: ``index_select`` with it costs
    about a tenth of indexing by a list at batch 1 (traced, a list index converts itself every call)."""
    key = (tuple(values), device)
    found = _indices.get(key)
    if found is None:
        # Made outside inference mode (an inference tensor could not be saved for a later backward
        # pass), once, so a trace records it as a constant.
        with torch.inference_mode(False):
            found = torch.tensor(key[0], dtype=torch.long, device=device)
        _indices[key] = found
    return found


_indices: dict[tuple[tuple[int, ...], torch.device], Tensor] = {}


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


class ChainKinematics:
    """Forward kinematics of only the joints on the way from the root to some ``ends``: the world rotations
    a depth level at a time (every joint of a level in one product), then every position in one pass, so both
    legs of a rig cost what one did (at batch 1 the joint-by-joint form is bound by per-operation dispatch).

    :attr:`joints` lists the joints computed, root first, a level after another; the results are
    in that order and :meth:`columns` finds joints in it.
    """

    def __init__(self, parents: Sequence[int], offsets: Tensor, ends: Sequence[int]) -> None:
        check_parents(parents)
        depth: dict[int, int] = {}
        for end in ends:
            way = [end]
            while parents[way[-1]] >= 0:
                way.append(parents[way[-1]])
            for j in reversed(way):
                depth[j] = 0 if parents[j] < 0 else depth[parents[j]] + 1
        levels = [sorted(j for j, d in depth.items() if d == level) for level in range(max(depth.values(), default=0) + 1)]
        self.joints: tuple[int, ...] = tuple(j for level in levels for j in level)
        self._column = {j: i for i, j in enumerate(self.joints)}  # where each joint is in the results
        # Per level below the root: its joints and where their parents are in the level above. For the
        # positions, computed at once from the world rotations: each joint's parent's column (the root's own,
        # with a zero offset), the offsets in the results' order, and which joints lie on the way from the root
        # to each (``ways[k, m]`` is 1 where joint ``m`` is on the way to ``k``, the root excluded). Tensors are
        # made outside inference mode, so autograd may use them whatever mode this object was made in.
        parent_column = [0] + [self._column[parents[j]] for j in self.joints[1:]]
        ways = [[0.0] * len(self.joints) for _ in self.joints]
        for k, j in enumerate(self.joints):
            while parents[j] >= 0:
                ways[k][self._column[j]] = 1.0
                j = parents[j]
        with torch.inference_mode(False):
            self._levels = [(level, [levels[i - 1].index(parents[j]) for j in level])
                            for i, level in enumerate(levels) if i > 0]
            self._parent_column = torch.tensor(parent_column, dtype=torch.long)
            self._offsets = torch.cat([torch.zeros_like(offsets[:1]), offsets[list(self.joints[1:])]])
            self._ways = torch.tensor(ways, dtype=offsets.dtype)

    def pick(self, results: Tensor, joints: Sequence[int]) -> Tensor:
        """The rows of ``joints`` (``[..., len(joints), C]``) from results ``[..., K, C]`` of this object."""
        return results.index_select(-2, constant_index(self.columns(joints), results.device))

    def columns(self, joints: Sequence[int]) -> list[int]:
        """Where ``joints`` are in the results (a ValueError for a joint not computed)."""
        missing = [j for j in joints if j not in self._column]
        if missing:
            raise ValueError(f"joints {missing} are not on the way to this kinematics' end joints")
        return [self._column[j] for j in joints]

    def __call__(self, local_rotations: Tensor, root_positions: Tensor) -> tuple[Tensor, Tensor]:
        """World ``(positions [..., K, 3], rotations [..., K, 4])`` of :attr:`joints`, from local
        rotations ``[..., J, 4]`` of the whole skeleton and ``root_positions [..., 3]``."""
        rot = local_rotations[..., :1, :]
        rotations = [rot]
        for joints, up in self._levels:
            if up == list(range(rot.shape[-2])) or rot.shape[-2] == 1:  # no gather: one child each, or the root's
                pass  # (quat_mul broadcasts the root's rotation over its children)
            else:
                rot = rot.index_select(-2, constant_index(up, rot.device))
            rot = quat_mul(rot, local_rotations.index_select(-2, constant_index(joints, local_rotations.device)))
            rotations.append(rot)
        world = torch.cat(rotations, dim=-2)
        # Each bone turned by its parent's world rotation in one pass, then summed along the way to each joint
        # (one product with the 0/1 matrix of the ways): at batch 1 a level at a time is bound by dispatch.
        dtype, device = world.dtype, world.device
        offsets = self._offsets.to(device, dtype).expand(*world.shape[:-1], 3)
        bones = quat_rotate(world.index_select(-2, self._parent_column.to(device)), offsets)
        return root_positions.unsqueeze(-2) + self._ways.to(device, dtype) @ bones, world


def feet_kinematics(skeleton: Skeleton) -> ChainKinematics:
    """:class:`ChainKinematics` of the joints on the way to the skeleton's feet: all that floor contact
    and the foot lock read (one object given to both lets the frame output compute it once)."""
    return ChainKinematics(skeleton.parents, skeleton.offsets_tensor(), skeleton.feet)


def global_to_local_rotations(global_rotations: Tensor, parents: Sequence[int]) -> Tensor:
    """Parent-relative rotations ``q_local[j] = q_global[parent]^-1 * q_global[j]`` ``[..., J, 4]``."""
    # A kept index tensor, not a list or a tensor made here: traced (model.inference.traced_step), it is a constant.
    parent_rot = global_rotations.index_select(-2, constant_index([max(p, 0) for p in parents], global_rotations.device))
    local = quat_mul(quat_conjugate(parent_rot), global_rotations)
    return torch.cat([global_rotations[..., :1, :], local[..., 1:, :]], dim=-2)


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
    from model.motion.rotations import axis_angle_to_quat  # local import keeps the module header small

    def unit(v: Tensor) -> Tensor:
        return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-8)

    # Like quantities go through together (three angles, two lengths' cosines, two axes, three
    # rotations): at batch 1 the solve is bound by per-operation dispatch, not by the arithmetic.
    ab, bc, ac, at = mid_pos - root_pos, end_pos - mid_pos, end_pos - root_pos, target - root_pos
    l1, l2, reach = torch.stack([ab, bc, at], dim=-2).norm(dim=-1).unbind(-1)
    d = reach.clamp((l1 - l2).abs() + eps, l1 + l2 - eps)
    # Now: the angles at the root (end, mid), at the mid joint (root, end) and at the root (end, target).
    # atan2 of the sine and cosine, not acos of the cosine: acos loses half the float32 digits near 0 and pi
    # (a foot moved a millimetre turned its leg by an angle off by 3e-4 rad, 0.03 cm at the ankle).
    u, v = torch.stack([ac, -ab, ac], dim=-2), torch.stack([ab, bc, at], dim=-2)
    now = torch.atan2(torch.linalg.cross(u, v).norm(dim=-1), (u * v).sum(-1))
    # Wanted, by the law of cosines for an end at distance d: the same two bend angles.
    # Sines from the triangle's area (Heron's factors, each at least eps once d is clamped), for the same atan2.
    area4 = ((l1 + l2 + d) * (l2 + d - l1) * (l1 + d - l2) * (l1 + l2 - d)).clamp_min(0.0).sqrt()  # 4 * area
    cosines = torch.stack([l1 * l1 + d * d - l2 * l2, l1 * l1 + l2 * l2 - d * d], -1)  # times 2 l1 d, 2 l1 l2
    wanted = torch.atan2(area4.unsqueeze(-1).expand_as(cosines), cosines)
    bend_turn = unit(torch.linalg.cross(torch.stack([ac, ac], dim=-2), torch.stack([ab, at], dim=-2)))  # the two axes
    r0, r1, r2 = axis_angle_to_quat(torch.cat([bend_turn[..., :1, :], bend_turn], dim=-2),  # bend, bend, turn
                                    torch.cat([wanted - now[..., :2], now[..., 2:]], dim=-1)).unbind(-2)
    # A straight chain has no bend plane; it needs no bend either, so drop the NaN-free zero axis.
    turn = quat_mul(r2, r0)
    return quat_mul(turn, root_rot), quat_mul(turn, quat_mul(r1, mid_rot))

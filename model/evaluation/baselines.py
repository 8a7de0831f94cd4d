"""Non-learned transition baselines (LaFAN1 / Harvey et al. 2020): interpolation and zero velocity.

Both are pure, batched functions on tensors. Given the last context pose (frame 0, not emitted)
and the target pose, they return the ``N`` generated frames ``1..N``; frame ``N`` **is** the
target, bit for bit, which matches how the model's transitions end on the target key frame.

Conventions: local (parent-relative) x,y,z,w quaternions ``[B, J, 4]``, root positions in cm
``[B, 3]`` (see :mod:`model.motion.rotations`, :mod:`model.motion.clip`). Run forward kinematics
(:func:`model.motion.kinematics.forward_kinematics`) on the output to get global positions for the metrics.

Sign convention of the output quaternions: the slerped frames take the sign of the target (the
context quaternion is flipped onto the target's hemisphere first), so the emitted frames are
continuous with each other and with the target. Apply
:func:`model.motion.rotations.quat_make_continuous` after concatenating with the context if a caller
needs sign continuity across the context boundary; the rotations themselves are unaffected.
"""

from __future__ import annotations

import torch

from model.motion.rotations import quat_slerp

Tensor = torch.Tensor


def _check(context_last_rot: Tensor, context_last_root: Tensor, target_rot: Tensor, target_root: Tensor, frames: int) -> None:
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    if context_last_rot.dim() != 3 or context_last_rot.shape[-1] != 4:
        raise ValueError(f"context_last_rot must be [B, J, 4], got {list(context_last_rot.shape)}")
    if target_rot.shape != context_last_rot.shape:
        raise ValueError(
            f"target_rot {list(target_rot.shape)} must match context_last_rot {list(context_last_rot.shape)}"
        )
    b = context_last_rot.shape[0]
    for name, root in (("context_last_root", context_last_root), ("target_root", target_root)):
        if root.shape != (b, 3):
            raise ValueError(f"{name} must be [{b}, 3], got {list(root.shape)}")


def interpolate(
    context_last_rot: Tensor,
    context_last_root: Tensor,
    target_rot: Tensor,
    target_root: Tensor,
    frames: int,
) -> tuple[Tensor, Tensor]:
    """Root lerp and per-joint slerp of local rotations from the last context pose to the target.

    Frame ``k`` (``1..N``, ``N = frames``) uses ``t = k / N``: the first emitted frame is ``1/N`` of
    the way, frame ``N`` equals the target exactly. Slerp takes the shorter arc
    (:func:`model.motion.rotations.quat_slerp`). Where the context and target quaternions are identical the
    context quaternion is returned unchanged, so a constant pose is reproduced exactly.

    Args:
        context_last_rot: ``[B, J, 4]`` local quaternions of the last context frame (t = 0).
        context_last_root: ``[B, 3]`` its root position (cm).
        target_rot: ``[B, J, 4]`` local quaternions of the target frame.
        target_root: ``[B, 3]`` target root position (cm).
        frames: ``N >= 1``, the number of frames to generate, target included.

    Returns:
        ``(rot [B, N, J, 4], root [B, N, 3])``.
    """
    _check(context_last_rot, context_last_root, target_rot, target_root, frames)
    dtype, device = context_last_rot.dtype, context_last_rot.device
    t = torch.arange(1, frames + 1, dtype=dtype, device=device) / frames  # [N]
    a = context_last_rot.unsqueeze(1)  # [B, 1, J, 4]
    b = target_rot.unsqueeze(1)
    a = torch.where((a * b).sum(-1, keepdim=True) < 0, -a, a)  # onto the target's hemisphere
    rot = quat_slerp(a, b, t[None, :, None])  # [B, N, J, 4]
    same = (a == b).all(dim=-1, keepdim=True)  # [B, 1, J, 1]
    rot = torch.where(same, b.expand_as(rot), rot)
    root = torch.lerp(context_last_root.unsqueeze(1), target_root.unsqueeze(1), t[None, :, None])  # [B, N, 3]
    rot[:, -1] = target_rot
    root[:, -1] = target_root
    return rot, root


def zero_velocity(
    context_last_rot: Tensor,
    context_last_root: Tensor,
    target_rot: Tensor,
    target_root: Tensor,
    frames: int,
) -> tuple[Tensor, Tensor]:
    """Hold the last context pose for frames ``1..N-1``, then jump to the target on frame ``N``.

    Same arguments and returns as :func:`interpolate`: ``(rot [B, N, J, 4], root [B, N, 3])``.
    """
    _check(context_last_rot, context_last_root, target_rot, target_root, frames)
    rot = context_last_rot.unsqueeze(1).repeat(1, frames, 1, 1)
    root = context_last_root.unsqueeze(1).repeat(1, frames, 1)
    rot[:, -1] = target_rot
    root[:, -1] = target_root
    return rot, root

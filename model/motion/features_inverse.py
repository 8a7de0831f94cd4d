"""The way back from a clip's style encoder input (:func:`model.motion.features.local_frame_features`) to its
global motion, up to where and which way it starts.

Each frame ``t`` keeps its joints relative to its root on the ground (``pos_t``) and their velocity
``p[t] - p[t-1]`` (``vel_t``), both turned by its facing, and its rotations turned the same way. So ``pos_t - vel_t``
is frame ``t-1`` in frame ``t``'s coordinates: its facing there is the turn from ``t`` back to ``t-1``, and the
root's ``vel_t`` on the ground is the step. Summing the turns and the steps rebuilds the path; the first kept frame
faces +Z over the origin. Where ``pos_t - vel_t`` is not frame ``t-1``'s pose (codes of several clips joined along
time, :mod:`model.inference.style_sets`), a new segment starts.
"""

from __future__ import annotations

import torch

from model.motion.features import facing_yaw
from model.motion.rotations import quat_mul, quat_rotate, sixd_to_quat, yaw_quat
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor
SEGMENT_BREAK_CM = 1.0  # a joint this far from where the next frame says it was: the clip before it has ended


def global_frames(features: Tensor, skeleton: Skeleton) -> tuple[Tensor, Tensor, Tensor]:
    """Global ``(positions [T, J, 3], rotations [T, J, 4] (quaternions), segment [T])`` of the frames whose
    features are ``features [T, J*12]``; ``segment`` counts from 0 and grows where a joined clip begins."""
    per_joint = features.unflatten(-1, (-1, 12))
    pos, vel, rot = per_joint[..., :3], per_joint[..., 3:6], per_joint[..., 6:]
    t, j = features.shape[0], per_joint.shape[1]
    r = skeleton.roles.root
    turn_back = facing_yaw(pos - vel, skeleton)  # [T]: frame t-1's facing in frame t's coordinates
    yaw = torch.cat([turn_back.new_zeros(1), -turn_back[1:]]).cumsum(0)
    facing = yaw_quat(yaw).view(t, 1, 4).expand(t, j, 4)
    steps = quat_rotate(facing[:, r], vel[:, r]) * torch.tensor([1.0, 0.0, 1.0], dtype=features.dtype)
    ground = torch.cat([steps.new_zeros(1, 3), steps[1:]]).cumsum(0)
    positions = quat_rotate(facing, pos) + ground.unsqueeze(1)
    before = positions[1:] - quat_rotate(facing[1:], vel[1:])
    breaks = (before - positions[:-1]).norm(dim=-1).amax(-1) > SEGMENT_BREAK_CM
    segment = torch.cat([breaks.new_zeros(1), breaks]).long().cumsum(0)
    rotations = quat_mul(facing, sixd_to_quat(rot))
    return positions, rotations, segment

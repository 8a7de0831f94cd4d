"""Whole-clip forms of ``model.motion``'s tensor functions, which only the tests use: a clip's features in
one frame's canonical frame, a clip mirrored left/right, and a skeleton's bone lengths."""

from __future__ import annotations

from dataclasses import replace

import torch

from model.motion.clip import Clip
from model.motion.features import CanonicalFrame, MotionFeatures, compute_features
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.mirror import mirror_global
from model.motion.skeleton import Skeleton


def clip_features(clip: Clip, reference_frame: int) -> tuple[MotionFeatures, CanonicalFrame]:
    """Features of a clip in the canonical frame of ``reference_frame``."""
    pos, rot = clip.global_transforms()
    frame = CanonicalFrame.at_frame(pos, clip.skeleton, reference_frame)
    return compute_features(frame.positions_to(pos), frame.rotations_to(rot), clip.skeleton), frame


def mirror_clip(clip: Clip, reflections: torch.Tensor | None = None) -> Clip:
    """The clip mirrored left/right (a left turn becomes a right turn) by :func:`model.motion.mirror.mirror_global`;
    ``reflections`` from :func:`model.motion.mirror.mirror_reflections` (from the rest offsets when omitted)."""
    sk = clip.skeleton
    pos, rot = forward_kinematics(clip.rotations.double(), clip.root_positions.double(), sk.offsets_tensor(torch.float64),
                                  sk.parents)
    mpos, mrot = mirror_global(pos, rot, sk, reflections)
    local = global_to_local_rotations(mrot, sk.parents)
    # The root lies on the midline, so it is its own counterpart.
    return replace(clip, rotations=local.to(clip.rotations.dtype), root_positions=mpos[..., 0, :].to(clip.root_positions.dtype))


def bone_lengths(skeleton: Skeleton) -> torch.Tensor:
    """Length of each joint's offset ``(J,)`` (0 for the root)."""
    lengths = skeleton.offsets_tensor(torch.float64).norm(dim=-1)
    lengths[0] = 0.0
    return lengths.float()

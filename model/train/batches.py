"""Turning windows of training motion into canonical pose states, as both later stages need."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.motion.features import CanonicalFrame, soft_contacts
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import PoseState, state_from_positions
from model.train.motion_tensors import MotionTensors

Tensor = torch.Tensor

# Position errors are divided by a typical bone length so position and 6D terms weigh alike (RSMT).
EDGE_CM = 21.0


@dataclass
class WindowBatch:
    """Windows in the canonical frame of one reference frame each.

    ``states`` is ``[B, L, J, *]``; ``phase`` ``[B, L, M, 2]``, ``amplitude``/``frequency``
    ``[B, L, M]``; ``contacts`` ``[B, L, F]`` soft foot contacts of the ground truth.
    """

    states: PoseState
    phase: Tensor | None
    amplitude: Tensor | None
    frequency: Tensor | None
    contacts: Tensor
    style: Tensor
    rotations: Tensor  # [B, L, J, 4] canonical world rotations


def make_batch(tensors: MotionTensors, starts: Tensor, owners: Tensor, length: int, reference: int,
               with_phase: bool = True) -> WindowBatch:
    pos, rot = tensors.gather(starts, length)
    sk = tensors.skeleton
    frame = CanonicalFrame.at_frame(pos, sk, reference)
    cpos, crot = frame.positions_to(pos), frame.rotations_to(rot)
    states = state_from_positions(cpos, quat_to_sixd(crot), sk.roles.root)
    # The first frame's velocity would be a copy; use the true one from the frame before when there is one.
    contacts = soft_contacts(states.vel[:, :, list(sk.feet)])
    ph = amp = fr = None
    if with_phase:
        ph, amp, fr = tensors.gather_phase(starts, length)
    # Style ids live on the CPU with the take bookkeeping; the batch lives where the motion does.
    return WindowBatch(states, ph, amp, fr, contacts, tensors.style[owners].to(pos.device), crot)


def foot_slide_loss(pred: PoseState, contacts: Tensor, feet: list[int]) -> Tensor:
    """Squared foot speed where the ground truth's foot is planted (RSMT's foot loss, cm/frame).

    ``pred`` is one frame ``[B, J, *]`` with ``contacts [B, F]``, or frames ``[B, L, J, *]`` with
    ``contacts [B, L, F]``: then each frame's contact-weighted mean is taken, and their mean over frames.
    """
    speed2 = (pred.vel[..., feet, :] ** 2).sum(-1)
    dims = (0, -1)  # batch and feet; frames stay apart
    per_frame = (contacts * speed2).sum(dims) / contacts.sum(dims).clamp_min(1.0)
    return per_frame.mean()

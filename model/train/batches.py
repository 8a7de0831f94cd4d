"""Turning windows of training motion into canonical pose states, as both later stages need."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.motion.features import CanonicalFrame, soft_contacts
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import PoseState, state_from_positions
from model.train.motion_tensors import MotionTensors
from model.train.time_warp import warped_rows

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

    @staticmethod
    def cat(batches: list[WindowBatch]) -> WindowBatch:
        """One batch of the windows of ``batches`` (of one length, all with or all without phases)."""

        def join(parts: list[Tensor | None]) -> Tensor | None:
            if any(x is None for x in parts):
                if not all(x is None for x in parts):
                    raise ValueError("cannot join windows with phase labels and windows without")
                return None
            return torch.cat([x for x in parts if x is not None])

        return WindowBatch(PoseState.cat([b.states for b in batches]), join([b.phase for b in batches]),
                           join([b.amplitude for b in batches]), join([b.frequency for b in batches]),
                           torch.cat([b.contacts for b in batches]), torch.cat([b.style for b in batches]),
                           torch.cat([b.rotations for b in batches]))


def make_batch(tensors: MotionTensors, starts: Tensor, owners: Tensor, length: int, reference: int,
               with_phase: bool = True) -> WindowBatch:
    """Windows of ``length`` frames starting at global rows ``starts`` (takes ``owners``), in the
    canonical frame of their frame ``reference``."""
    pos, rot = tensors.gather(starts, length)
    phase = tensors.gather_phase(starts, length) if with_phase else None
    return _batch(tensors, pos, rot, phase, owners, reference)


def make_warped_batch(tensors: MotionTensors, starts: Tensor, owners: Tensor, context: int, length: int,
                      factor: Tensor, ramp: int, with_phase: bool = True) -> WindowBatch:
    """Windows of ``context`` captured frames and a transition of ``length`` frames replaying
    ``factor [B]`` times as much of the capture (:mod:`model.train.time_warp`), in the canonical frame
    of their last context frame."""
    rows, speed = warped_rows(starts, context, length, factor, ramp)
    pos, rot = tensors.gather_at(rows)
    phase = tensors.gather_phase_at(rows, speed) if with_phase else None
    return _batch(tensors, pos, rot, phase, owners, context - 1)


def _batch(tensors: MotionTensors, pos: Tensor, rot: Tensor, phase: tuple[Tensor, Tensor, Tensor] | None,
           owners: Tensor, reference: int) -> WindowBatch:
    sk = tensors.skeleton
    frame = CanonicalFrame.at_frame(pos, sk, reference)
    cpos, crot = frame.positions_to(pos), frame.rotations_to(rot)
    states = state_from_positions(cpos, quat_to_sixd(crot), sk.roles.root)
    # The first frame's velocity would be a copy; use the true one from the frame before when there is one.
    contacts = soft_contacts(states.vel[:, :, list(sk.feet)])
    ph, amp, fr = phase if phase is not None else (None, None, None)
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

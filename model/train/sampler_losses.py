"""The sampler's training losses: how a rollout of generated transitions is scored.

Frame-wise terms against the capture (positions, rotations, forward kinematics, phase, foot
contact, the phase estimator), the last frame against the target, motion-texture terms
(velocities, each joint's acceleration profile, the velocity spectrum), planted-foot sliding, and
the frozen style critics' verdict. Windows without ground truth (another style's clip, changed
controls) get only the terms that need none.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from model.evaluation.metrics import ground_contact_weight
from model.motion.skeleton import Skeleton
from model.nets.sampler import TransitionSampler
from model.nets.style_classifier import StyleClassifier, motion_features
from model.train.batches import EDGE_CM, WindowBatch, foot_slide_loss
from model.train.motion_tensors import MotionTensors
from model.train.sampler_config import SamplerStageConfig
from model.train.sampler_rollout import Rollout, fk_from_states, rollout

Tensor = torch.Tensor


def critic_logits(critics: Sequence[StyleClassifier], positions: Tensor, skeleton: Skeleton) -> list[Tensor]:
    """Each critic's logits for canonical world positions ``[B, T+1, J, 3]`` (the last context frame first).

    Critics read positions only (their inputs are velocity-based), so identity rotations stand in
    and no gradient has to pass through a 6D-to-quaternion conversion.
    """
    rot = positions.new_zeros(*positions.shape[:-1], 4)
    rot[..., 3] = 1.0  # x, y, z, w
    features = motion_features(positions, rot, skeleton)
    return [critic(features) for critic in critics]


def score_rollout(r: Rollout, tensors: MotionTensors, cfg: SamplerStageConfig, rows: slice = slice(None),
                  critics: Sequence[StyleClassifier] = (), critic_labels: Tensor | None = None, ground_truth: bool = True,
                  ground: Tensor | None = None, clip_acc: Tensor | None = None) -> dict[str, Tensor]:
    """The losses of the windows ``rows`` of a rollout (``critic_labels`` are those rows' own); see
    :func:`transition_losses`. Every loss is a mean over the given rows only. ``clip_acc [rows, J]``, the
    acceleration profile of each row's style clip, adds the ``clip_acc`` loss (no ground truth needed)."""
    k = r.context
    feet = list(tensors.skeleton.feet)
    target, last = r.target.index(rows), r.last.index(rows)
    pred_fk, before = r.pred_fk[rows], r.before[rows]
    out = {
        "last_pos": ((last.positions() - target.positions()).abs() / EDGE_CM).mean(),
        "last_rot": (last.rot - target.rot).abs().mean(),
    }
    frames = torch.cat([before[:, 1:], pred_fk], 1)  # the last context frame, then the generated ones
    pred_vel = torch.diff(torch.cat([before, pred_fk], 1), dim=1)
    if clip_acc is not None:
        out["clip_acc"] = (acceleration_profile(pred_vel) - clip_acc).abs().mean() / EDGE_CM
    if ground is not None:
        out["foot_height"] = planted_foot_speed(frames, feet, ground)
    if critics and critic_labels is not None and r.steps >= cfg.style_loss_min_frames:
        known = critic_labels >= 0
        if known.any():
            labels = critic_labels[known]
            logits = critic_logits(critics, frames[known], tensors.skeleton)
            out["style"] = torch.stack([nn.functional.cross_entropy(x, labels) for x in logits]).mean()
            out["style_acc"] = torch.stack([(x.argmax(-1) == labels).float().mean() for x in logits]).mean()
    if not ground_truth:
        return out
    batch, length = r.batch, r.length
    assert batch.phase is not None and batch.amplitude is not None and batch.frequency is not None
    s = batch.states.index(rows)
    est_p, est_a, est_f = (e[rows] for e in r.estimate)
    gp, ga, gf = batch.phase[rows, k - 1], batch.amplitude[rows, k - 1], batch.frequency[rows, k - 1]
    est_loss = (est_p - gp).pow(2).mean() + (est_a - ga).pow(2).mean() + (est_f - gf).pow(2).mean()
    # All frames at once: each per-frame term averages the same number of elements, so the mean over
    # frames of per-frame means is the mean over the stacked frames (far fewer autograd nodes).
    gen_states = r.gen_states.index(rows)
    aux = {name: v[rows] for name, v in r.aux.items()}
    gt_states = s.index((slice(None), slice(k, k + length)))
    gp, ga, gf = batch.phase[rows, k:k + length], batch.amplitude[rows, k:k + length], batch.frequency[rows, k:k + length]
    phase_loss = ((aux["phase"] - gp).pow(2).mean() + (aux["phase_hat"] - gp).pow(2).mean()
                  + (aux["amplitude"] - ga).pow(2).mean() + (aux["frequency"] - gf).pow(2).mean())
    gt_fk = fk_from_states(gt_states.rot, gt_states.positions()[:, :, r.root], tensors)
    gt_vel = torch.diff(torch.cat([before, gt_fk], 1), dim=1)
    return {
        **out,
        "pos": ((gen_states.positions() - gt_states.positions()).abs() / EDGE_CM).mean(),
        "rot": (gen_states.rot - gt_states.rot).abs().mean(),
        "phase": phase_loss,
        "foot": foot_slide_loss(gen_states, batch.contacts[rows, k:k + length], feet),
        "fk": ((pred_fk - gt_fk).abs() / EDGE_CM).mean(),
        "estimator": est_loss,
        "vel": ((pred_vel[:, 1:] - gt_vel[:, 1:]).abs() / EDGE_CM).mean(),
        "acc": (acceleration_profile(pred_vel) - acceleration_profile(gt_vel)).abs().mean() / EDGE_CM,
        "spectrum": (velocity_spectrum(pred_vel[:, 1:]) - velocity_spectrum(gt_vel[:, 1:])).abs().mean(),
        "fk_error_cm": (pred_fk - gt_fk).norm(dim=-1).mean(),
        "last_fk_error_cm": (pred_fk[:, -1] - gt_fk[:, -1]).norm(dim=-1).mean(),
    }


def transition_losses(model: TransitionSampler, tensors: MotionTensors, batch: WindowBatch, style_feats: Tensor,
                      length: int, cfg: SamplerStageConfig, gen: torch.Generator | None, training: bool,
                      critics: Sequence[StyleClassifier] = (), critic_labels: Tensor | None = None,
                      ground_truth: bool = True, ground: Tensor | None = None, duration: int | None = None,
                      target_shift: Tensor | None = None, target_turn: Tensor | None = None) -> dict[str, Tensor]:
    """Generate ``length`` frames for every window of ``batch`` and score them.

    Changed controls (no ground truth): ``duration`` generates that many frames towards the window's
    target instead, ``target_shift [B, 2]`` moves the target's root (x, z) in the canonical frame and
    ``target_turn [B]`` turns the target pose about its own vertical axis (radians).

    With ``ground_truth`` False (style clips of another style than the content's) only what needs
    no ground-truth in-between is scored: reaching the target, and the critics' style loss (their
    mean cross-entropy; ``style_acc`` is their mean accuracy). ``critic_labels`` are the critics'
    class per window (-1: a style they do not know; all critics share one style list). ``ground``
    (the foot joints' ground levels, cm) adds the ``foot_height`` loss, which needs no ground truth.
    """
    if (duration is not None or target_shift is not None or target_turn is not None) and ground_truth:
        raise ValueError("changed controls have no ground-truth in-between frames")
    r = rollout(model, tensors, batch, style_feats, length, cfg, gen, training, duration, target_shift, target_turn)
    return score_rollout(r, tensors, cfg, critics=critics, critic_labels=critic_labels,
                         ground_truth=ground_truth, ground=ground)


def weighted_sum(losses: dict[str, Tensor], weights: dict[str, float]) -> Tensor:
    """``sum(weights[k] * losses[k])`` over the weighted losses present, in ``weights``' order."""
    terms = [w * losses[k] for k, w in weights.items() if k in losses]
    return sum(terms[1:], terms[0])  # left to right, as the terms are listed


def planted_foot_speed(positions: Tensor, feet: list[int], ground: Tensor) -> Tensor:
    """Horizontal speed of foot joints weighted by how close each is to its ground level (cm/frame).

    The weighting of :func:`model.evaluation.metrics.foot_skate` (1 on the ground, 0 from 2.5 cm up), applied to
    the generated motion itself: the ground-truth contact loss only holds feet still when the
    capture's feet were down, which misses a generated step that lands a few frames off. The weight
    is detached, so the loss slows a foot on the ground rather than lifting it off.
    """
    p = positions[:, :, feet]
    speed = (p[:, 1:, :, [0, 2]] - p[:, :-1, :, [0, 2]]).pow(2).sum(-1).add(1e-6).sqrt()
    w = ground_contact_weight((p[:, 1:, :, 1] - ground).detach())
    return (speed * w).sum() / (w > 0).sum().clamp_min(1)


def velocity_spectrum(velocity: Tensor, floor: float = 0.1) -> Tensor:
    """Log power spectrum over time of each joint's velocity, ``[B, L, J, 3]`` to ``[B, L // 2 + 1, J]``.

    Frame-wise losses leave a sampler with too much 5-15 Hz jitter and too little 2-4 Hz motion
    (measured on the first default model: 1.4-1.9x and 0.8x the capture's power there). Comparing
    spectra asks for the capture's rhythm and smoothness without asking for its exact timing.
    ``floor`` (cm^2/frame^2) keeps near-silent bins from dominating the log.
    """
    v = velocity - velocity.mean(dim=1, keepdim=True)
    power = torch.view_as_real(torch.fft.rfft(v, dim=1)).pow(2).sum((-1, -2))  # re² + im², summed over x, y, z
    return torch.log(power + floor)


def acceleration_profile(velocity: Tensor) -> Tensor:
    """Mean acceleration magnitude of each joint over a transition, ``[B, L, J, 3]`` velocities to ``[B, J]``.

    A deterministic sampler cannot place every fine accent of a style where the capture has it,
    and frame-wise losses then pull its output towards either a smooth mean or uncorrelated
    jitter; matching how strongly each joint accelerates, wherever it does, keeps the amount of
    motion texture a style has without asking for its timing.
    """
    acc = torch.diff(velocity, dim=1)
    return (acc.pow(2).sum(-1) + 1e-8).sqrt().mean(dim=1)  # eps: a finite gradient at rest

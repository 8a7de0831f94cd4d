"""Generating a batch of training transitions with the sampler: the rollout every sampler loss scores.

Each window holds ``context`` frames, then a transition whose last frame is the target; the
sampler generates the transition frame by frame from the context towards the target.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from model.inference.output.steering import SteeringConfig, shifted, steering_shift
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.rotations import quat_mul, quat_rotate, quat_to_sixd, sixd_to_quat, yaw_quat
from model.nets.pose_state import PoseState
from model.nets.sampler import TransitionSampler
from model.train.batches import WindowBatch
from model.train.motion_tensors import MotionTensors
from model.train.sampler_config import SamplerStageConfig

Tensor = torch.Tensor


def fk_from_states(rot6: Tensor, root_pos: Tensor, tensors: MotionTensors) -> Tensor:
    """World joint positions of canonical pose states: global 6D rotations ``rot6`` and root positions ``root_pos``."""
    sk = tensors.skeleton
    local = global_to_local_rotations(sixd_to_quat(rot6), sk.parents)
    return forward_kinematics(local, root_pos, sk.offsets_tensor().to(rot6.device), sk.parents)[0]


def turn_target(target: PoseState, angle: Tensor) -> PoseState:
    """Targets ``[B, J, *]`` turned by ``angle [B]`` radians about their own root's vertical axis (the
    evaluation's "turned" control): the pose turns in place, its root stays where it was."""
    q = yaw_quat(angle).view(-1, 1, 4).expand(-1, target.rel.shape[1], 4)
    turn = q.to(target.rel.dtype)
    rel = quat_rotate(turn, target.rel)  # offsets from the root's ground point: turning them turns about it
    vel = quat_rotate(turn, target.vel)
    rot = quat_to_sixd(quat_mul(turn, sixd_to_quat(target.rot)))
    return PoseState(rel, vel, rot, target.root_xz)


@dataclass
class Rollout:
    """A batch of generated transitions and what scoring them needs (:func:`rollout`)."""

    batch: WindowBatch
    context: int  # context frames of each window
    root: int  # the root joint's index
    length: int  # ground-truth frames of each window's transition
    steps: int  # frames generated
    target: PoseState  # [B, J, *]
    last: PoseState  # the last generated frame
    estimate: tuple[Tensor, Tensor, Tensor]  # the phase estimator's (phase, amplitude, frequency) of the last context frame
    gen_states: PoseState  # [B, steps, J, *]
    aux: dict[str, Tensor]  # per-frame phase predictions, [B, steps, ...]
    pred_fk: Tensor  # [B, steps, J, 3] joint positions
    before: Tensor  # [B, 2, J, 3] the two context frames before the transition


def rollout(model: TransitionSampler, tensors: MotionTensors, batch: WindowBatch, style_feats: Tensor, length: int,
            cfg: SamplerStageConfig, gen: torch.Generator | None, training: bool, duration: int | None = None,
            target_shift: Tensor | None = None, target_turn: Tensor | None = None) -> Rollout:
    """Generate ``length`` frames (``duration`` if given) for every window of ``batch`` towards its target,
    moved by ``target_shift [B, 2]`` (root x, z in the canonical frame) and turned by ``target_turn [B]``
    radians about its own vertical axis if given.

    With ``cfg.target_velocity_drop`` above 0, that fraction of training windows (and every
    validation window: what a game sends by default) get their target without its velocity.
    """
    c = model.config
    k = c.context
    s = batch.states
    b = s.rel.shape[0]
    steps = length if duration is None else duration
    style = model.style_context(model.encode_style(style_feats))
    assert batch.phase is not None and batch.amplitude is not None and batch.frequency is not None
    # Contiguous copies: a view's strides depend on the window's length, and compiled steps
    # (model.train.step_compiler) are specialised to strides.
    ctx = s.index((slice(None), slice(0, k))).contiguous()
    est_p, est_a, est_f = model.phase_estimator(ctx.vector())
    dev = s.rel.device
    if training and gen is not None:
        gt_p, gt_a, gt_f = batch.phase[:, k - 1], batch.amplitude[:, k - 1], batch.frequency[:, k - 1]
        # Drawn from the step's CPU generator, then moved: the same draws on every device.
        use_gt = (torch.rand(b, generator=gen) < cfg.gt_phase_probability).view(b, 1).to(dev)
        start_phase = (torch.where(use_gt.unsqueeze(-1), gt_p, est_p.detach()), torch.where(use_gt, gt_a, est_a.detach()),
                       torch.where(use_gt, gt_f, est_f.detach()))
        noise = (torch.randn(b, 2 * c.width, generator=gen) * c.noise_std).to(dev)
    else:
        start_phase = None
        noise = torch.zeros(b, 2 * c.width, device=dev)
    known = None
    if cfg.target_velocity_drop > 0:
        # Drawn after every earlier draw of the step, so runs without the drop draw what they did.
        known = (torch.rand(b, generator=gen) >= cfg.target_velocity_drop).to(dev) if training and gen is not None \
            else torch.zeros(b, dtype=torch.bool, device=dev)
    target = s.index((slice(None), k + length - 1)).contiguous()
    if target_shift is not None:
        target = PoseState(target.rel, target.vel, target.rot, target.root_xz + target_shift)
    if target_turn is not None:
        target = turn_target(target, target_turn)
    state = model.begin(ctx, target, torch.full((b,), steps, device=dev), noise, style, start_phase, known)
    poses, auxes = [], []
    changed = duration is not None or target_shift is not None or target_turn is not None
    steering = SteeringConfig(window=cfg.steering_window) if cfg.steering_window > 0 and changed else None
    for _ in range(steps):
        state, aux = model.step(state, style)
        if steering is not None:
            # The engine's steering (model.inference.output.steering), as a push from outside: no gradient
            # flows through the shift, so the losses teach the gait that goes with being carried.
            # Changed-control windows only: steering the windows scored against the capture frame by
            # frame degraded every loss within 200 steps (docs/experiments/2026-11-25-steering.md).
            with torch.no_grad():
                shift = steering_shift(state, c.root, steering)
            state = shifted(state, shift)
        poses.append(state.pose)
        auxes.append(aux)
    # The generated frames stacked once ([B, steps, J, *]) for every loss.
    gen_states = PoseState.stack(poses, 1)
    return Rollout(
        batch=batch, context=k, root=c.root, length=length, steps=steps, target=target, last=state.pose,
        estimate=(est_p, est_a, est_f), gen_states=gen_states,
        aux={name: torch.stack([a[name] for a in auxes], 1) for name in ("phase", "phase_hat", "amplitude", "frequency")},
        pred_fk=fk_from_states(gen_states.rot, gen_states.positions()[:, :, c.root], tensors),
        before=fk_from_states(s.rot[:, k - 2:k], s.positions()[:, k - 2:k, c.root], tensors),
    )


def concat_batches(a: WindowBatch, b: WindowBatch) -> WindowBatch:
    """The windows of ``a`` then those of ``b`` (same length), to generate in one rollout."""
    def cat(x: Tensor | None, y: Tensor | None) -> Tensor | None:
        return None if x is None or y is None else torch.cat([x, y])

    return WindowBatch(PoseState.cat([a.states, b.states]), cat(a.phase, b.phase), cat(a.amplitude, b.amplitude),
                       cat(a.frequency, b.frequency),
                       torch.cat([a.contacts, b.contacts]), torch.cat([a.style, b.style]),
                       torch.cat([a.rotations, b.rotations]))

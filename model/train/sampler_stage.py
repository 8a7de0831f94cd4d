"""Stage 3: train the style-conditioned sampler on top of the frozen manifold decoder.

Each batch holds windows of one style: ``context`` frames, then a transition of ``L`` frames whose
last frame is the target; every window is paired with a style clip from another window of the
same style. ``L`` follows a curriculum from short to long transitions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import nn

from model.evaluation.metrics import ground_contact_weight, ground_levels
from model.motion.features import local_frame_features
from model.motion.kinematics import forward_kinematics, global_to_local_rotations
from model.motion.rotations import sixd_to_quat
from model.motion.skeleton import Skeleton
from model.nets.pose_state import PoseState
from model.nets.sampler import TransitionSampler
from model.nets.style_classifier import StyleClassifier, motion_features
from model.train.batches import EDGE_CM, WindowBatch, foot_slide_loss, make_batch
from model.train.loop import LoopConfig, LoopResult, resolve_device, step_generator, train_loop
from model.train.motion_tensors import MotionTensors
from model.train.step_compiler import compiled_steps

Tensor = torch.Tensor

CRITIC_INPUTS = ("velocity", "dynamics", "acceleration")  # input selections that depend on positions only

@dataclass
class SamplerStageConfig:
    loop: LoopConfig = field(default_factory=lambda: LoopConfig(iterations=3000, epoch_iterations=300, lr=1e-3,
                                                                weight_decay=1e-4))
    batch: int = 32
    min_transition: int = 5
    max_transition: int = 60
    curriculum: float = 0.3  # fraction of training after which any length up to the maximum is drawn
    style_frames: int = 120
    gt_phase_probability: float = 0.5
    w_pos: float = 1.0
    w_rot: float = 1.0
    w_last_pos: float = 1.0
    w_last_rot: float = 0.5
    w_phase: float = 0.5
    w_foot: float = 0.05
    w_fk: float = 0.5
    w_estimator: float = 0.5
    w_vel: float = 0.0  # joint velocities against the ground truth's
    w_acc: float = 0.0  # each joint's mean acceleration against the ground truth's (acceleration_profile)
    w_spectrum: float = 0.0  # log power spectrum of joint velocities against the ground truth's (velocity_spectrum)
    w_foot_height: float = 0.0  # horizontal speed of generated feet at their ground height (planted_foot_speed)
    w_style: float = 0.0  # cross-entropy of the style critic on generated frames (0: no critic)
    cross_batch: int = 0  # windows per step with a style clip of another style (need w_style)
    # Those windows have no ground truth: this weighs each joint's mean acceleration over the transition
    # against the style clip's own (acceleration_profile), the clip being the only example of its style at hand.
    w_clip_acc: float = 0.0
    # The critics' loss on those other-style windows (None: w_style). They are the only windows that ask
    # the sampler to follow a clip against its context, and they are scored on little else.
    w_cross_style: float | None = None
    # Windows per step with changed controls, scored without ground truth (reaching the target, feet,
    # critics): half get a duration scaled by a factor in [1/control_dt, control_dt], half a target
    # moved by x times the window's own root travel, x in [-control_shift, control_shift] (the
    # evaluation's d = 2 and d = -1 are x = 1 and x = -2). Natural windows alone never ask for either.
    control_batch: int = 0
    control_dt: float = 2.0
    control_shift: float = 2.0
    # Each critic's input selection (model.nets.style_classifier.INPUTS, velocity-based); the style loss is
    # their mean, so generated motion has to satisfy critics that read it differently, not one net's blind spots.
    critic_inputs: tuple[str, ...] = ("dynamics",)
    critic_epochs: int = 6
    critic_iterations: int = 150
    style_loss_min_frames: int = 16  # shorter transitions get no style loss: too short to show a style
    extra_losses_from: int = 0  # step from which w_vel, w_acc, w_spectrum, w_foot_height, w_style and cross pairs apply
    validation_transition: int = 40

    def __post_init__(self) -> None:
        if isinstance(self.critic_inputs, str):  # configs written before critics became a list
            self.critic_inputs = (self.critic_inputs,)
        self.critic_inputs = tuple(self.critic_inputs)
        bad = [c for c in self.critic_inputs if c not in CRITIC_INPUTS]
        if bad or not self.critic_inputs or len(set(self.critic_inputs)) != len(self.critic_inputs):
            # Critics read positions only (critic_logits): no gradient through 6D-to-quaternion conversions.
            raise ValueError(f"critic_inputs must be distinct selections among {', '.join(CRITIC_INPUTS)}, "
                             f"got {list(self.critic_inputs)!r}")
        if self.cross_batch < 0 or self.control_batch < 0:
            raise ValueError("cross_batch and control_batch must be 0 or more")
        if self.w_cross_style is not None and self.w_cross_style < 0:
            raise ValueError(f"w_cross_style must be 0 or more (or null: w_style), got {self.w_cross_style}")
        if self.control_dt < 1.0 or self.control_shift < 0.0:
            raise ValueError("control_dt must be at least 1 and control_shift at least 0")


def style_statistics(tensors: MotionTensors, frames: int, samples: int = 2048, seed: int = 0) -> tuple[Tensor, Tensor]:
    """Per-channel mean and std of style-clip features over random training windows."""
    starts, _ = tensors.window_starts(frames, max(1, frames // 4))
    gen = torch.Generator().manual_seed(seed)
    pick = starts[torch.randperm(len(starts), generator=gen)[:samples]]
    feats = []
    for chunk in pick.split(256):
        pos, rot = tensors.gather(chunk, frames)
        feats.append(local_frame_features(pos, rot, tensors.skeleton).flatten(0, 1))
    x = torch.cat(feats)
    return x.mean(0), x.std(0).clamp_min(1e-2)


class StylePairs:
    """Windows grouped by style, for content windows and for style clips."""

    def __init__(self, tensors: MotionTensors, length: int, style_frames: int, step: int = 5) -> None:
        starts, owners = tensors.window_starts(length, step)
        sstarts, sowners = tensors.window_starts(style_frames, max(1, style_frames // 4))
        self.by_style: dict[int, tuple[Tensor, Tensor]] = {}
        self.clips_by_style: dict[int, tuple[Tensor, Tensor]] = {}
        for s in tensors.style.unique().tolist():
            m = tensors.style[owners] == s
            ms = tensors.style[sowners] == s
            if m.any() and ms.any():
                self.by_style[s] = (starts[m], owners[m])
                self.clips_by_style[s] = (sstarts[ms], sowners[ms])
        if not self.by_style:
            raise ValueError(f"no take is long enough for {length}-frame windows and {style_frames}-frame style clips")
        self.styles = sorted(self.by_style)

    def sample_cross(self, batch: int, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor, int]:
        """Content windows of one style with style clips of another: ``(starts, owners, clip starts, clip style)``."""
        if len(self.styles) < 2:
            raise ValueError("cross-style pairs need at least two styles")
        s = self.styles[int(torch.randint(len(self.styles), (1,), generator=gen))]
        others = [o for o in self.styles if o != s]
        o = others[int(torch.randint(len(others), (1,), generator=gen))]
        starts, owners = self.by_style[s]
        pick = torch.randint(len(starts), (batch,), generator=gen)
        cs, _ = self.clips_by_style[o]
        return starts[pick], owners[pick], cs[torch.randint(len(cs), (batch,), generator=gen)], o

    def sample(self, batch: int, gen: torch.Generator) -> tuple[Tensor, Tensor, Tensor]:
        s = self.styles[int(torch.randint(len(self.styles), (1,), generator=gen))]
        starts, owners = self.by_style[s]
        pick = torch.randint(len(starts), (batch,), generator=gen)
        cs, co = self.clips_by_style[s]
        # Prefer style clips from another take than the content window's, so style cannot be copied.
        cpick = torch.randint(len(cs), (batch,), generator=gen)
        same = co[cpick] == owners[pick]
        if same.any() and (co != co[0]).any():
            cpick[same] = torch.randint(len(cs), (int(same.sum()),), generator=gen)
        return starts[pick], owners[pick], cs[cpick]


def _fk_from_states(rot6: Tensor, root_pos: Tensor, tensors: MotionTensors) -> Tensor:
    sk = tensors.skeleton
    local = global_to_local_rotations(sixd_to_quat(rot6), sk.parents)
    return forward_kinematics(local, root_pos, sk.offsets_tensor().to(rot6.device), sk.parents)[0]


def cross_style_weights(weights: dict[str, float], stage: SamplerStageConfig) -> dict[str, float]:
    """The loss weights of the other-style windows: ``weights`` with the critics' at ``w_cross_style``."""
    return dict(weights) if stage.w_cross_style is None else {**weights, "style": stage.w_cross_style}


def critic_logits(critics: Sequence[StyleClassifier], positions: Tensor, skeleton: Skeleton) -> list[Tensor]:
    """Each critic's logits for canonical world positions ``[B, T+1, J, 3]`` (the last context frame first).

    Critics read positions only (their inputs are velocity-based), so identity rotations stand in
    and no gradient has to pass through a 6D-to-quaternion conversion.
    """
    rot = positions.new_zeros(*positions.shape[:-1], 4)
    rot[..., 3] = 1.0  # x, y, z, w
    features = motion_features(positions, rot, skeleton)
    return [critic(features) for critic in critics]


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
            target_shift: Tensor | None = None) -> Rollout:
    """Generate ``length`` frames (``duration`` if given) for every window of ``batch`` towards its target,
    moved by ``target_shift [B, 2]`` (root x, z in the canonical frame) if given."""
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
    target = s.index((slice(None), k + length - 1)).contiguous()
    if target_shift is not None:
        target = PoseState(target.rel, target.vel, target.rot, target.root_xz + target_shift)
    state = model.begin(ctx, target, torch.full((b,), steps, device=dev), noise, style, start_phase)
    poses, auxes = [], []
    for _ in range(steps):
        state, aux = model.step(state, style)
        poses.append(state.pose)
        auxes.append(aux)
    # The generated frames stacked once ([B, steps, J, *]) for every loss.
    gen_states = PoseState.stack(poses, 1)
    return Rollout(
        batch=batch, context=k, root=c.root, length=length, steps=steps, target=target, last=state.pose,
        estimate=(est_p, est_a, est_f), gen_states=gen_states,
        aux={name: torch.stack([a[name] for a in auxes], 1) for name in ("phase", "phase_hat", "amplitude", "frequency")},
        pred_fk=_fk_from_states(gen_states.rot, gen_states.positions()[:, :, c.root], tensors),
        before=_fk_from_states(s.rot[:, k - 2:k], s.positions()[:, k - 2:k, c.root], tensors),
    )


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
    gt_fk = _fk_from_states(gt_states.rot, gt_states.positions()[:, :, r.root], tensors)
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
                      target_shift: Tensor | None = None) -> dict[str, Tensor]:
    """Generate ``length`` frames for every window of ``batch`` and score them.

    Changed controls (no ground truth): ``duration`` generates that many frames towards the window's
    target instead, and ``target_shift [B, 2]`` moves the target's root (x, z) in the canonical frame.

    With ``ground_truth`` False (style clips of another style than the content's) only what needs
    no ground-truth in-between is scored: reaching the target, and the critics' style loss (their
    mean cross-entropy; ``style_acc`` is their mean accuracy). ``critic_labels`` are the critics'
    class per window (-1: a style they do not know; all critics share one style list). ``ground``
    (the foot joints' ground levels, cm) adds the ``foot_height`` loss, which needs no ground truth.
    """
    if (duration is not None or target_shift is not None) and ground_truth:
        raise ValueError("changed controls have no ground-truth in-between frames")
    r = rollout(model, tensors, batch, style_feats, length, cfg, gen, training, duration, target_shift)
    return score_rollout(r, tensors, cfg, critics=critics, critic_labels=critic_labels,
                         ground_truth=ground_truth, ground=ground)


def concat_batches(a: WindowBatch, b: WindowBatch) -> WindowBatch:
    """The windows of ``a`` then those of ``b`` (same length), to generate in one rollout."""
    def cat(x: Tensor | None, y: Tensor | None) -> Tensor | None:
        return None if x is None or y is None else torch.cat([x, y])

    return WindowBatch(PoseState.cat([a.states, b.states]), cat(a.phase, b.phase), cat(a.amplitude, b.amplitude),
                       cat(a.frequency, b.frequency),
                       torch.cat([a.contacts, b.contacts]), torch.cat([a.style, b.style]),
                       torch.cat([a.rotations, b.rotations]))


def train_sampler(train: MotionTensors, val: MotionTensors, model: TransitionSampler, stage: SamplerStageConfig,
                  folder: Path, progress: bool = True, device: torch.device | str = "auto",
                  critics: Sequence[StyleClassifier] = (), compile: bool = False) -> tuple[TransitionSampler, LoopResult]:
    """Train every sampler module except the decoder, which stays frozen (gradients flow through it).

    ``model`` is moved to ``device`` (in place) and stays there. With ``stage.w_style`` above 0,
    ``critics`` (style classifiers trained on the training split, frozen) add a style loss on the
    generated frames, and ``stage.cross_batch`` windows per step get a style clip of another style
    (no ground truth: only the target and the critic's loss apply to them). ``compile`` runs the
    per-frame functions through ``torch.compile`` (:mod:`model.train.step_compiler`).
    """
    c = model.config
    if stage.max_transition > c.max_transition:
        raise ValueError("the stage's max_transition exceeds the model's")
    dev = resolve_device(device)
    model.to(dev)
    train, val = train.to(dev), val.to(dev)
    mean, std = style_statistics(train, stage.style_frames, seed=stage.loop.seed)
    model.style_mean.copy_(mean)
    model.style_std.copy_(std)
    for p in model.decoder.parameters():
        p.requires_grad_(False)
    params = [(n, p) for n, p in model.named_parameters() if not n.startswith("decoder.")]
    length_max = c.context + stage.max_transition
    pairs = StylePairs(train, length_max, stage.style_frames)
    vpairs = StylePairs(val, c.context + stage.validation_transition, stage.style_frames, step=20)
    vgen = torch.Generator().manual_seed(stage.loop.seed + 1)
    val_sets = [vpairs.sample(16, vgen) for _ in range(4)]
    use_critic = stage.w_style > 0
    if use_critic:
        if not critics:
            raise ValueError("w_style > 0 needs a style critic")
        for critic in critics:
            if critic.config.inputs not in CRITIC_INPUTS:
                raise ValueError(f"a style critic must read velocities only ({', '.join(CRITIC_INPUTS)}), "
                                 f"not {critic.config.inputs!r}")
            if critic.styles != critics[0].styles:
                raise ValueError("the style critics must share one list of styles")
            critic.to(dev).eval()
            for p in critic.parameters():
                p.requires_grad_(False)
        # The critics' class of each of the data's style ids (-1: a style they were not trained on).
        known_styles = critics[0].styles
        class_of = torch.tensor([known_styles.index(n) if n in known_styles else -1 for n in train.styles])

    ground = ground_levels(train.positions, list(train.skeleton.feet)).to(dev) if stage.w_foot_height > 0 else None

    # Loss weights by name; a loss a step did not compute (no critic, no ground truth) is skipped.
    base_weights = {"pos": stage.w_pos, "rot": stage.w_rot, "last_pos": stage.w_last_pos, "last_rot": stage.w_last_rot,
                    "phase": stage.w_phase, "foot": stage.w_foot, "fk": stage.w_fk, "estimator": stage.w_estimator}
    weights = {**base_weights, "vel": stage.w_vel, "acc": stage.w_acc, "spectrum": stage.w_spectrum,
               "foot_height": stage.w_foot_height, "style": stage.w_style, "clip_acc": stage.w_clip_acc}

    cross_weights = cross_style_weights(weights, stage)

    def labels_of(style_ids: Tensor) -> Tensor | None:
        return class_of[style_ids.cpu()].to(dev) if use_critic else None

    def features_of(style_starts: Tensor, tensors: MotionTensors) -> Tensor:
        pos, rot = tensors.gather(style_starts, stage.style_frames)
        return local_frame_features(pos, rot, tensors.skeleton)

    def control_losses(length: int, gen: torch.Generator) -> dict[str, Tensor]:
        """Windows of ``length`` frames with a scaled duration (first half) or a moved target (second half)."""
        n = stage.control_batch
        cs, co, cclips = pairs.sample(n, gen)
        scale = math.exp((2 * float(torch.rand(1, generator=gen)) - 1) * math.log(stage.control_dt))
        duration = max(stage.min_transition, min(c.max_transition, round(length * scale)))
        x = (2 * torch.rand(n, 1, generator=gen) - 1) * stage.control_shift
        out: dict[str, list[Tensor]] = {}
        for rows, moved in ((slice(0, n // 2), False), (slice(n // 2, n), True)):
            if rows.stop <= rows.start:
                continue
            cb = make_batch(train, cs[rows], co[rows], c.context + length, c.context - 1)
            if moved:
                # The window's own root travel over the gap, scaled: the evaluation's "location" control.
                travel = cb.states.root_xz[:, c.context + length - 1] - cb.states.root_xz[:, c.context - 1]
                kw: dict = {"target_shift": travel * x[rows].to(travel.device)}
            else:
                kw = {"duration": duration}
            losses = transition_losses(model, train, cb, features_of(cclips[rows], train), length, stage, gen, True,
                                       critics if use_critic else (), labels_of(train.style[co[rows]]),
                                       ground_truth=False, ground=ground, **kw)
            for key, v in losses.items():
                out.setdefault(key, []).append(v)
        return {key: torch.stack(v).mean() for key, v in out.items()}

    def step(i: int) -> dict[str, float]:
        gen = step_generator(stage.loop.seed, i)
        longest = curriculum_length(i, stage)
        length = int(torch.randint(stage.min_transition, max(stage.min_transition, longest) + 1, (1,), generator=gen))
        starts, owners, style_starts = pairs.sample(stage.batch, gen)
        batch = make_batch(train, starts, owners, c.context + length, c.context - 1)
        extra = i >= stage.extra_losses_from
        styled = use_critic and extra
        labels = labels_of(train.style[owners])
        feats = features_of(style_starts, train)
        cross = styled and stage.cross_batch > 0 and length >= stage.style_loss_min_frames
        if cross:
            # Windows with a style clip of another style, generated in the same rollout as the batch's own:
            # the recurrent loop's cost is mostly per operation, not per window (about 0.2 s a step saved).
            xs, xo, xclips, xstyle = pairs.sample_cross(stage.cross_batch, gen)
            xlabels = labels_of(torch.full((len(xs),), xstyle))
            batch = concat_batches(batch, make_batch(train, xs, xo, c.context + length, c.context - 1))
            xpos, xrot = train.gather(xclips, stage.style_frames)
            feats = torch.cat([feats, local_frame_features(xpos, xrot, train.skeleton)])
        r = rollout(model, train, batch, feats, length, stage, gen, True)
        own = slice(0, stage.batch)
        losses = score_rollout(r, train, stage, own, critics if styled else (), labels,
                               ground=ground if extra else None)
        total = weighted_sum(losses, weights if extra else base_weights)
        shown = {k: v.item() for k, v in losses.items() if k in ("pos", "fk_error_cm", "last_fk_error_cm", "foot", "phase",
                                                                  "acc", "style_acc", "foot_height", "spectrum")}
        if cross:
            clip_acc = acceleration_profile(torch.diff(xpos, dim=1)) if stage.w_clip_acc > 0 else None
            xl = score_rollout(r, train, stage, slice(stage.batch, None), critics, xlabels, ground_truth=False, ground=ground,
                               clip_acc=clip_acc)
            if "style_acc" in xl:
                shown["cross_acc"] = xl["style_acc"].item()
            if "clip_acc" in xl:
                shown["clip_acc"] = xl["clip_acc"].item()
            total = total + weighted_sum(xl, cross_weights) * (stage.cross_batch / stage.batch)
        if extra and stage.control_batch > 0:
            cl = control_losses(length, gen)
            if "style_acc" in cl:
                shown["control_acc"] = cl["style_acc"].item()
            shown["control_last"] = cl["last_pos"].item()
            total = total + weighted_sum(cl, weights) * (stage.control_batch / stage.batch)
        total.backward()
        return shown

    def validate() -> dict[str, float]:
        sums: dict[str, float] = {}
        for starts, owners, style_starts in val_sets:
            length = stage.validation_transition
            batch = make_batch(val, starts, owners, c.context + length, c.context - 1)
            out = transition_losses(model, val, batch, features_of(style_starts, val), length, stage, None, False,
                                    critics if use_critic else (), labels_of(val.style[owners]), ground=ground)
            for k, v in out.items():
                sums[k] = sums.get(k, 0.0) + v.item() / len(val_sets)
        return {k: sums[k] for k in ("fk_error_cm", "last_fk_error_cm", "foot", "phase", "estimator", "acc", "style_acc",
                                     "foot_height", "spectrum") if k in sums}

    with compiled_steps(model, compile):
        result = train_loop("sampler", folder, model, params, stage.loop, step, validate, progress)
    model.eval()
    return model, result


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


def curriculum_length(step: int, stage: SamplerStageConfig) -> int:
    """The longest transition drawn at ``step``: rises linearly from the shortest to the longest over
    the first ``curriculum`` fraction of training."""
    frac = min(1.0, step / max(1, stage.loop.iterations * stage.curriculum))
    return int(stage.min_transition + math.floor(frac * (stage.max_transition - stage.min_transition)))

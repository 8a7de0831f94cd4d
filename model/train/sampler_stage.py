"""Stage 3: train the style-conditioned sampler on top of the frozen manifold decoder.

Each batch holds windows of one style: ``context`` frames, then a transition of ``L`` frames whose
last frame is the target; every window is paired with a style clip from another window of the
same style. ``L`` follows a curriculum from short to long transitions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import torch

from model.features import local_frame_features
from model.kinematics import forward_kinematics, global_to_local_rotations
from model.rotations import sixd_to_quat
from model.sampler import SamplerConfig, TransitionSampler
from model.train.batches import EDGE_CM, WindowBatch, foot_slide_loss, make_batch
from model.train.loop import LoopConfig, LoopResult, resolve_device, step_generator, train_loop
from model.train.motion_tensors import MotionTensors

Tensor = torch.Tensor


@dataclass
class SamplerStageConfig:
    loop: LoopConfig = field(default_factory=lambda: LoopConfig(iterations=3000, epoch_iterations=300, lr=1e-3, weight_decay=1e-4))
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
    validation_transition: int = 40


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


def transition_losses(model: TransitionSampler, tensors: MotionTensors, batch: WindowBatch, style_feats: Tensor,
                      length: int, cfg: SamplerStageConfig, gen: torch.Generator | None, training: bool) -> dict[str, Tensor]:
    c = model.config
    k = c.context
    s = batch.states
    b = s.rel.shape[0]
    feet = list(tensors.skeleton.feet)
    code = model.encode_style(style_feats)
    style = model.style_context(code)
    assert batch.phase is not None and batch.amplitude is not None and batch.frequency is not None
    ctx = s.index((slice(None), slice(0, k)))
    est_p, est_a, est_f = model.phase_estimator(ctx.vector())
    gt_p, gt_a, gt_f = batch.phase[:, k - 1], batch.amplitude[:, k - 1], batch.frequency[:, k - 1]
    est_loss = (est_p - gt_p).pow(2).mean() + (est_a - gt_a).pow(2).mean() + (est_f - gt_f).pow(2).mean()
    dev = s.rel.device
    if training and gen is not None:
        # Drawn from the step's CPU generator, then moved: the same draws on every device.
        use_gt = (torch.rand(b, generator=gen) < cfg.gt_phase_probability).view(b, 1).to(dev)
        start_phase = (torch.where(use_gt.unsqueeze(-1), gt_p, est_p.detach()), torch.where(use_gt, gt_a, est_a.detach()),
                       torch.where(use_gt, gt_f, est_f.detach()))
        noise = (torch.randn(b, 2 * c.width, generator=gen) * c.noise_std).to(dev)
    else:
        start_phase = None
        noise = torch.zeros(b, 2 * c.width, device=dev)
    target = s.index((slice(None), k + length - 1))
    state = model.begin(ctx, target, torch.full((b,), length, device=dev), noise, style, start_phase)
    pos_l, rot_l, ph_l, foot_l = [], [], [], []
    rots, roots = [], []
    for t in range(length):
        state, aux = model.step(state, style)
        gt = s.index((slice(None), k + t))
        pos_l.append(((state.pose.positions() - gt.positions()).abs() / EDGE_CM).mean())
        rot_l.append((state.pose.rot - gt.rot).abs().mean())
        gp, ga, gf = batch.phase[:, k + t], batch.amplitude[:, k + t], batch.frequency[:, k + t]
        ph_l.append((aux["phase"] - gp).pow(2).mean() + (aux["phase_hat"] - gp).pow(2).mean()
                    + (aux["amplitude"] - ga).pow(2).mean() + (aux["frequency"] - gf).pow(2).mean())
        foot_l.append(foot_slide_loss(state.pose, batch.contacts[:, k + t], feet))
        rots.append(state.pose.rot)
        roots.append(state.pose.positions()[:, c.root])
    pred_fk = _fk_from_states(torch.stack(rots, 1), torch.stack(roots, 1), tensors)
    gt_states = s.index((slice(None), slice(k, k + length)))
    gt_fk = _fk_from_states(gt_states.rot, gt_states.positions()[:, :, c.root], tensors)
    last = state.pose
    return {
        "pos": torch.stack(pos_l).mean(),
        "rot": torch.stack(rot_l).mean(),
        "last_pos": ((last.positions() - target.positions()).abs() / EDGE_CM).mean(),
        "last_rot": (last.rot - target.rot).abs().mean(),
        "phase": torch.stack(ph_l).mean(),
        "foot": torch.stack(foot_l).mean(),
        "fk": ((pred_fk - gt_fk).abs() / EDGE_CM).mean(),
        "estimator": est_loss,
        "fk_error_cm": (pred_fk - gt_fk).norm(dim=-1).mean(),
        "last_fk_error_cm": (pred_fk[:, -1] - gt_fk[:, -1]).norm(dim=-1).mean(),
    }


def train_sampler(train: MotionTensors, val: MotionTensors, model: TransitionSampler, stage: SamplerStageConfig,
                  folder: Path, progress: bool = True,
                  device: torch.device | str = "auto") -> tuple[TransitionSampler, LoopResult]:
    """Train every sampler module except the decoder, which stays frozen (gradients flow through it).

    ``model`` is moved to ``device`` (in place) and stays there.
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
    gen = torch.Generator().manual_seed(stage.loop.seed)
    vgen = torch.Generator().manual_seed(stage.loop.seed + 1)
    val_sets = [vpairs.sample(16, vgen) for _ in range(4)]

    def features_of(style_starts: Tensor, tensors: MotionTensors) -> Tensor:
        pos, rot = tensors.gather(style_starts, stage.style_frames)
        return local_frame_features(pos, rot, tensors.skeleton)

    def step(i: int) -> dict[str, float]:
        gen = step_generator(stage.loop.seed, i)
        longest = curriculum_length(i, stage)
        length = int(torch.randint(stage.min_transition, max(stage.min_transition, longest) + 1, (1,), generator=gen))
        starts, owners, style_starts = pairs.sample(stage.batch, gen)
        batch = make_batch(train, starts, owners, c.context + length, c.context - 1)
        losses = transition_losses(model, train, batch, features_of(style_starts, train), length, stage, gen, True)
        total = (stage.w_pos * losses["pos"] + stage.w_rot * losses["rot"] + stage.w_last_pos * losses["last_pos"]
                 + stage.w_last_rot * losses["last_rot"] + stage.w_phase * losses["phase"] + stage.w_foot * losses["foot"]
                 + stage.w_fk * losses["fk"] + stage.w_estimator * losses["estimator"])
        total.backward()
        return {k: v.item() for k, v in losses.items() if k in ("pos", "fk_error_cm", "last_fk_error_cm", "foot", "phase")}

    def validate() -> dict[str, float]:
        sums: dict[str, float] = {}
        for starts, owners, style_starts in val_sets:
            length = stage.validation_transition
            batch = make_batch(val, starts, owners, c.context + length, c.context - 1)
            out = transition_losses(model, val, batch, features_of(style_starts, val), length, stage, None, False)
            for k, v in out.items():
                sums[k] = sums.get(k, 0.0) + v.item() / len(val_sets)
        return {k: sums[k] for k in ("fk_error_cm", "last_fk_error_cm", "foot", "phase", "estimator")}

    result = train_loop("sampler", folder, model, params, stage.loop, step, validate, progress)
    model.eval()
    return model, result


def curriculum_length(step: int, stage: SamplerStageConfig) -> int:
    """The longest transition drawn at ``step``: rises linearly from the shortest to the longest over
    the first ``curriculum`` fraction of training."""
    frac = min(1.0, step / max(1, stage.loop.iterations * stage.curriculum))
    return int(stage.min_transition + math.floor(frac * (stage.max_transition - stage.min_transition)))

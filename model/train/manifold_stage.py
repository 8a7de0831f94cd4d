"""Stage 2: train the motion manifold (VAE + phase-gated mixture-of-experts decoder) by rollout."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch

from model.nets.manifold import ManifoldConfig, MotionManifold
from model.train.batches import EDGE_CM, WindowBatch, foot_slide_loss, make_batch
from model.train.loop import LoopConfig, LoopResult, cpu_randn_like, seeded_start, step_generator, train_loop
from model.train.motion_tensors import MotionTensors

Tensor = torch.Tensor


@dataclass
class ManifoldStageConfig:
    loop: LoopConfig = field(default_factory=lambda: LoopConfig(iterations=3000, epoch_iterations=300, lr=1e-3))
    batch: int = 64
    window: int = 25  # two given frames, then 23 predicted autoregressively (RSMT)
    kl_weight: float = 1e-3
    foot_weight: float = 0.1
    rot_weight: float = 1.0


def rollout_losses(model: MotionManifold, batch: WindowBatch, cfg: ManifoldStageConfig, feet: list[int],
                   sample: bool = True) -> dict[str, Tensor]:
    """Roll the decoder from frame 1 over the window; root motion and phases come from the data."""
    s = batch.states
    root = model.config.root
    state = s.index((slice(None), 1))
    pos_l, rot_l, kl_l, foot_l = [], [], [], []
    for t in range(1, s.rel.shape[1] - 1):
        gt = s.index((slice(None), t + 1))
        mu, logvar = model.encoder(state.vector(), gt.vector())
        z = mu + cpu_randn_like(mu) * torch.exp(0.5 * logvar) if sample else mu
        assert batch.phase is not None
        state = model.decoder.step(state, gt.vel[:, root], gt.rot[:, root], z, batch.phase[:, t + 1])
        pos_l.append(((state.positions() - gt.positions()) / EDGE_CM).pow(2).mean())
        rot_l.append((state.rot - gt.rot).pow(2).mean())
        kl_l.append(-0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).mean())
        foot_l.append(foot_slide_loss(state, batch.contacts[:, t + 1], feet))
    return {k: torch.stack(v).mean() for k, v in (("pos", pos_l), ("rot", rot_l), ("kl", kl_l), ("foot", foot_l))}


def train_manifold(train: MotionTensors, val: MotionTensors, config: ManifoldConfig, stage: ManifoldStageConfig,
                   folder: Path, progress: bool = True,
                   device: torch.device | str = "auto") -> tuple[MotionManifold, LoopResult]:
    """Fit encoder and decoder by rollout on windows of the training takes; the model is returned on ``device``."""
    model, train, val = seeded_start(lambda: MotionManifold(config), stage.loop.seed, train, val, device)
    feet = list(train.skeleton.feet)
    starts, owners = train.window_starts(stage.window, 5)
    vstarts, vowners = val.window_starts(stage.window, stage.window)
    gen = torch.Generator().manual_seed(stage.loop.seed)
    pick = torch.randperm(len(vstarts), generator=gen)[:256]
    val_batch = make_batch(val, vstarts[pick], vowners[pick], stage.window, 0)

    def step(i: int) -> dict[str, float]:
        gen = step_generator(stage.loop.seed, i)
        idx = torch.randint(len(starts), (stage.batch,), generator=gen)
        batch = make_batch(train, starts[idx], owners[idx], stage.window, 0)
        losses = rollout_losses(model, batch, stage, feet)
        foot_w = stage.foot_weight if i > stage.loop.epoch_iterations else 0.0  # RSMT: feet after the first epoch
        total = losses["pos"] + stage.rot_weight * losses["rot"] + stage.kl_weight * losses["kl"] + foot_w * losses["foot"]
        total.backward()
        return {k: v.item() for k, v in losses.items()}

    def validate() -> dict[str, float]:
        losses = rollout_losses(model, val_batch, stage, feet, sample=False)
        out = {k: v.item() for k, v in losses.items()}
        out["pos_rmse_cm"] = (losses["pos"].item() ** 0.5) * EDGE_CM
        return out

    result = train_loop("manifold", folder, model, list(model.named_parameters()), stage.loop, step, validate, progress)
    model.eval()
    return model, result

"""Stage 1: train the periodic autoencoder and label every training frame with its phase."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch
from tqdm import tqdm

from model.motion.features import facing_yaw
from model.motion.rotations import quat_rotate, yaw_quat
from model.nets.phase import PeriodicAutoencoder, PhaseConfig, label_phases
from model.train.loop import LoopConfig, LoopResult, resolve_device, seeded_start, step_generator, train_loop
from model.train.motion_tensors import MotionTensors

Tensor = torch.Tensor


@dataclass
class PhaseStageConfig:
    loop: LoopConfig = field(default_factory=lambda: LoopConfig(iterations=1500, epoch_iterations=250, lr=1e-3,
                                                                weight_decay=1e-4))
    batch: int = 64


def local_velocities(tensors: MotionTensors) -> Tensor:
    """PAE input per frame ``[N, J*3]``: change of each joint's position in its frame's own canonical
    frame (facing +Z over the root); frame 0 of each take repeats frame 1."""
    sk = tensors.skeleton
    pos = tensors.positions
    yaw = facing_yaw(pos, sk)
    ground = pos[:, sk.roles.root].clone()
    ground[:, 1] = 0.0
    local = quat_rotate(yaw_quat(-yaw).unsqueeze(1), pos - ground.unsqueeze(1))
    vel = torch.zeros_like(local)
    vel[1:] = local[1:] - local[:-1]
    first = tensors.take_start.to(vel.device)
    vel[first] = vel[(first + 1).clamp(max=len(vel) - 1)]
    return vel.flatten(1)


def _window_batch(vel: Tensor, centres: Tensor, window: int) -> Tensor:
    half = window // 2
    idx = (centres.unsqueeze(1) + torch.arange(-half, half + 1)).to(vel.device)
    win = vel[idx].transpose(1, 2)  # [B, C, W]
    return win - win.mean(dim=-1, keepdim=True)


def _centres(tensors: MotionTensors, window: int) -> Tensor:
    half = window // 2
    out = []
    for i in range(tensors.num_takes):
        s, n = int(tensors.take_start[i]), int(tensors.take_len[i])
        if n > window:
            out.append(torch.arange(s + half, s + n - half))
    return torch.cat(out)


def train_phase(train: MotionTensors, val: MotionTensors, config: PhaseConfig, stage: PhaseStageConfig,
                folder: Path, progress: bool = True,
                device: torch.device | str = "auto") -> tuple[PeriodicAutoencoder, LoopResult]:
    """Fit the PAE on centred velocity windows of the training takes; the model is returned on ``device``."""
    model, train, val = seeded_start(lambda: PeriodicAutoencoder(config), stage.loop.seed, train, val, device)
    vel_train, vel_val = local_velocities(train), local_velocities(val)
    c_train, c_val = _centres(train, config.window), _centres(val, config.window)
    gen = torch.Generator().manual_seed(stage.loop.seed)
    val_idx = c_val[torch.randperm(len(c_val), generator=gen)[:512]]

    def step(i: int) -> dict[str, float]:
        gen = step_generator(stage.loop.seed, i)
        centres = c_train[torch.randint(len(c_train), (stage.batch,), generator=gen)]
        x = _window_batch(vel_train, centres, config.window)
        recon, _ = model(x)
        loss = torch.nn.functional.mse_loss(recon, x)
        loss.backward()
        return {"mse": loss.item()}

    def validate() -> dict[str, float]:
        x = _window_batch(vel_val, val_idx, config.window)
        recon, params = model(x)
        return {"mse": torch.nn.functional.mse_loss(recon, x).item(),
                "explained": 1.0 - ((recon - x) ** 2).mean().item() / x.var().item(),
                "mean_freq_hz": params["frequency"].mean().item()}

    result = train_loop("phase", folder, model, list(model.named_parameters()), stage.loop, step, validate, progress)
    model.eval()
    return model, result


def label_tensors(model: PeriodicAutoencoder, tensors: MotionTensors, progress: bool = True,
                  device: torch.device | str | None = None) -> None:
    """Fill ``tensors.phase``, ``amplitude`` and ``frequency`` for every frame.

    The frequency label is the frame-to-frame advance of each channel's shift (wrapped to half a
    cycle), in cycles per second: the quantity the sampler's phase update integrates.

    The labelling runs on ``device`` (default: where the model is); the model is put back where it
    was afterwards, and the labels are stored on the device of ``tensors.positions``.
    """
    home = next(model.parameters()).device
    dev = home if device is None else resolve_device(device)
    model.to(dev)
    vel = local_velocities(tensors.to(dev))
    m = model.config.phases
    n = len(vel)
    phase = torch.zeros(n, m, 2, device=dev)
    amp = torch.zeros(n, m, device=dev)
    freq = torch.zeros(n, m, device=dev)
    for i in tqdm(range(tensors.num_takes), desc="phase labels", disable=not progress, leave=False):
        sl = tensors.take_slice(i)
        out = label_phases(model, vel[sl])
        phase[sl], amp[sl] = out["phase"], out["amplitude"] * model.config.amplitude_scale
        shift = out["shift"]
        d = shift[1:] - shift[:-1]
        d = d - torch.round(d)
        f = torch.cat([d[:1], d]) * model.config.fps if len(d) else torch.zeros_like(shift)
        freq[sl] = f
    model.to(home)
    where = tensors.positions.device
    tensors.phase, tensors.amplitude, tensors.frequency = phase.to(where), amp.to(where), freq.to(where)


def phase_summary(tensors: MotionTensors) -> dict[str, float]:
    """Means that show whether the labels are sane (frequencies of walking are about 1-2 Hz)."""
    assert tensors.frequency is not None and tensors.amplitude is not None
    return {"mean_abs_freq_hz": tensors.frequency.abs().mean().item(), "mean_amplitude": tensors.amplitude.mean().item()}

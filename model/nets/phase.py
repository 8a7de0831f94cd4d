"""The phase model: a periodic autoencoder after DeepPhase, and a causal current-phase estimator.

The periodic autoencoder (PAE) reads a window of joint velocities, squeezes it through ``M``
latent curves, and describes each curve by a sinusoid (amplitude ``A``, frequency ``F``, offset
``B``, shift ``S``). It labels every frame of the data with a phase vector per channel,
``p = A * (cos 2 pi S, sin 2 pi S)`` (scaled by ``amplitude_scale``). Those labels look half a
window into the future, so inference never uses them: :class:`PhaseEstimator` predicts the phase
of the last context frame from the context alone, and the sampler carries phase forward itself.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

Tensor = torch.Tensor


@dataclass
class PhaseConfig:
    """Shapes of the phase model.

    Attributes:
        channels: input channels (joints * 3 velocity components).
        phases: latent phase channels ``M``.
        window: frames per window (odd, centred on the labelled frame).
        hidden: width of the convolutional encoder/decoder.
        fps: frame rate of the windows; frequencies are in cycles per second.
        amplitude_scale: factor applied to ``A`` in phase vectors (RSMT uses 10).
    """

    channels: int = 66
    phases: int = 8
    window: int = 61
    hidden: int = 32
    fps: float = 30.0
    amplitude_scale: float = 10.0

    def to_dict(self) -> dict:
        return asdict(self)


class PeriodicAutoencoder(nn.Module):
    """DeepPhase PAE: ``x [B, C, W]`` (zero-mean per channel) to per-channel sinusoid parameters."""

    # Buffers (registered in __init__).
    freqs: Tensor
    tau: Tensor

    def __init__(self, config: PhaseConfig) -> None:
        super().__init__()
        c = config
        if c.window % 2 != 1:
            raise ValueError("the phase window must have an odd number of frames")
        self.config = c
        k, pad = c.window, c.window // 2
        self.enc1 = nn.Conv1d(c.channels, c.hidden, k, padding=pad)
        self.enc_norm1 = nn.BatchNorm1d(c.hidden)
        self.enc2 = nn.Conv1d(c.hidden, c.phases, k, padding=pad)
        self.enc_norm2 = nn.BatchNorm1d(c.phases)
        # One (sx, sy) projection per phase channel, packed as a grouped 1x1 conv over time.
        self.shift = nn.Conv1d(c.phases, 2 * c.phases, c.window, groups=c.phases)
        self.shift_norm = nn.BatchNorm1d(2 * c.phases)
        self.dec1 = nn.Conv1d(c.phases, c.hidden, k, padding=pad)
        self.dec_norm1 = nn.BatchNorm1d(c.hidden)
        self.dec2 = nn.Conv1d(c.hidden, c.channels, k, padding=pad)
        # Window time axis spans (window-1)/fps seconds; frequencies of the rfft bins in Hz.
        duration = c.window / c.fps
        self.register_buffer("freqs", torch.arange(1, c.window // 2 + 1, dtype=torch.float32) / duration, persistent=False)
        self.register_buffer("tau", (torch.arange(c.window, dtype=torch.float32) - c.window // 2) / c.fps, persistent=False)

    def encode(self, x: Tensor, fft: bool = False) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """Latent curves and their sinusoid parameters.

        ``fft`` runs the two encoder convolutions through FFTs (:func:`same_conv_fft`): the same
        result to float rounding and several times faster, since each kernel spans the whole window.

        Returns:
            ``latent [B, M, W]``, ``amplitude [B, M]``, ``frequency [B, M]`` (Hz),
            ``offset [B, M]``, ``shift [B, M]`` (cycles, in (-0.5, 0.5]).
        """
        conv = same_conv_fft if fft else (lambda inputs, layer: layer(inputs))
        h = torch.tanh(self.enc_norm1(conv(x, self.enc1)))
        latent = torch.tanh(self.enc_norm2(conv(h, self.enc2)))
        spec = torch.fft.rfft(latent, dim=-1)
        power = spec[..., 1:].abs() ** 2
        total = power.sum(-1).clamp_min(1e-8)
        w = self.config.window
        frequency = (power * self.freqs).sum(-1) / total
        amplitude = 2.0 * torch.sqrt(total) / w
        offset = spec[..., 0].real / w
        s = self.shift_norm(self.shift(latent)).squeeze(-1)  # [B, 2M]
        sx, sy = s[:, 0::2], s[:, 1::2]
        shift = torch.atan2(sy, sx) / (2 * math.pi)
        return latent, amplitude, frequency, offset, shift

    def forward(self, x: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        """Reconstruct ``x [B, C, W]`` through the sinusoids; returns the reconstruction and parameters."""
        latent, a, f, b, s = self.encode(x)
        tau = self.tau.view(1, 1, -1)
        curves = a.unsqueeze(-1) * torch.sin(2 * math.pi * (f.unsqueeze(-1) * tau + s.unsqueeze(-1))) + b.unsqueeze(-1)
        h = torch.tanh(self.dec_norm1(self.dec1(curves)))
        return self.dec2(h), {"latent": latent, "curves": curves, "amplitude": a, "frequency": f, "offset": b, "shift": s}


def same_conv_fft(x: Tensor, conv: nn.Conv1d) -> Tensor:
    """``conv(x)`` for a "same"-padded ``nn.Conv1d`` (odd kernel, padding ``kernel // 2``, stride 1, no
    groups or dilation) on ``x [B, C, W]``, computed as a product of spectra.

    The phase model's kernels are as long as its windows (61 frames), so a direct convolution costs
    ``C * O * W * K`` multiply-adds per window and the spectral product about ``C * O * W``: labelling
    every frame of the data is several times faster this way.
    """
    k = conv.kernel_size[0]
    if conv.padding != (k // 2,) or conv.stride != (1,) or conv.groups != 1 or conv.dilation != (1,) or k % 2 != 1:
        raise ValueError("same_conv_fft takes an odd-kernel, stride-1, 'same'-padded convolution without groups")
    w = x.shape[-1]
    n = 1 << (w + k - 2).bit_length()  # at least w + k - 1 points: the circular product is the linear one
    # nn.Conv1d correlates; the flipped kernel turns that into a convolution, whose middle w samples are the output.
    spectrum = torch.einsum("bcf,ocf->bof", torch.fft.rfft(x, n=n), torch.fft.rfft(conv.weight.flip(-1), n=n))
    y = torch.fft.irfft(spectrum, n=n)[..., k // 2: k // 2 + w]
    return y if conv.bias is None else y + conv.bias.view(1, -1, 1)


def phase_vectors(amplitude: Tensor, shift: Tensor, scale: float) -> Tensor:
    """``[..., M]`` amplitude and shift to phase vectors ``[..., M, 2]`` = A*scale*(cos, sin)(2 pi S)."""
    angle = 2 * math.pi * shift
    return torch.stack([torch.cos(angle), torch.sin(angle)], dim=-1) * (amplitude * scale).unsqueeze(-1)


def velocity_windows(velocities: Tensor, window: int) -> Tensor:
    """All centred windows of a take's velocities ``[T, C]`` as ``[T, C, window]``, zero-mean.

    The ends are padded by repeating the first and last velocity, so every frame gets a label
    (the reference trims half a window at each end instead, losing a second of each short take).
    """
    half = window // 2
    padded = torch.cat([velocities[:1].expand(half, -1), velocities, velocities[-1:].expand(half, -1)], dim=0)
    win = padded.unfold(0, window, 1)  # [T, C, window]
    return win - win.mean(dim=-1, keepdim=True)


@torch.no_grad()
def label_phases(model: PeriodicAutoencoder, velocities: Tensor, batch: int = 512) -> dict[str, Tensor]:
    """Per-frame phase parameters of one take from its velocities ``[T, C]`` (cm/frame).

    Returns ``amplitude``, ``frequency``, ``shift`` ``[T, M]`` and ``phase`` ``[T, M, 2]``.
    """
    model.eval()
    windows = velocity_windows(velocities, model.config.window)
    parts = [model.encode(windows[i : i + batch], fft=True) for i in range(0, len(windows), batch)]
    amp = torch.cat([p[1] for p in parts])
    freq = torch.cat([p[2] for p in parts])
    shift = torch.cat([p[4] for p in parts])
    return {
        "amplitude": amp,
        "frequency": freq,
        "shift": shift,
        "phase": phase_vectors(amp, shift, model.config.amplitude_scale),
    }


def advance_phase(phase: Tensor, amplitude: Tensor, frequency: Tensor, dt: float) -> Tensor:
    """Rotate each phase vector ``[..., M, 2]`` by ``2 pi F dt`` and give it amplitude ``[..., M]``."""
    angle = 2 * math.pi * frequency * dt
    c, s = torch.cos(angle), torch.sin(angle)
    unit = phase / phase.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    x, y = unit[..., 0], unit[..., 1]
    rotated = torch.stack([c * x - s * y, s * x + c * y], dim=-1)
    return rotated * amplitude.unsqueeze(-1)


def blend_phase(a: Tensor, b: Tensor) -> Tensor:
    """Halfway blend of two phase vectors ``[..., M, 2]``: mean direction, mean amplitude (slerp at 0.5)."""
    na, nb = a.norm(dim=-1, keepdim=True), b.norm(dim=-1, keepdim=True)
    direction = a / na.clamp_min(1e-6) + b / nb.clamp_min(1e-6)
    direction = direction / direction.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    return direction * 0.5 * (na + nb)


class PhaseEstimator(nn.Module):
    """Causal estimate of the last context frame's phase from the context states alone.

    Input ``[B, K, D]`` (K context frames of pose-state vectors); output phase ``[B, M, 2]``,
    amplitude ``[B, M]`` and frequency ``[B, M]``.
    """

    def __init__(self, state_dim: int, context: int, phases: int, hidden: int = 256) -> None:
        super().__init__()
        self.phases = phases
        self.net = nn.Sequential(
            nn.Linear(state_dim * context, hidden), nn.ELU(), nn.Linear(hidden, hidden), nn.ELU(),
            nn.Linear(hidden, phases * 4),
        )

    def forward(self, context_states: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        out = self.net(context_states.flatten(1))
        m = self.phases
        phase = out[:, : 2 * m].view(-1, m, 2)
        return phase, out[:, 2 * m : 3 * m], out[:, 3 * m :]

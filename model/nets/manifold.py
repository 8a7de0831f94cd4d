"""The motion manifold: a VAE whose decoder is a phase-gated mixture of experts predicting pose change.

The decoder takes the current pose state, the root's motion for the next frame (its displacement
and its rotation, which the sampler decides), a latent code ``z`` and the next phase, and predicts
every joint's velocity and 6D rotation change. Experts are blended on their *outputs*: each layer
runs all experts as one matrix product and mixes the results, which costs the same as blending
weights at batch 1 and stays fast at large batches (blending weight matrices per sample does not).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from torch import nn

from model.nets.pose_state import PoseState, integrate, state_dim

Tensor = torch.Tensor


@dataclass
class ManifoldConfig:
    """Shapes of the motion manifold.

    Attributes:
        joints: skeleton joints ``J``.
        phases: phase channels ``M`` of the gating input (2M values).
        latent: size of ``z``.
        experts: number of experts.
        hidden: width of the expert layers.
        gate_hidden: width of the gating network.
        encoder_hidden: width of the (training-only) encoder.
        root: index of the root joint.
    """

    joints: int = 22
    phases: int = 8
    latent: int = 32
    experts: int = 4
    hidden: int = 256
    gate_hidden: int = 64
    encoder_hidden: int = 256
    root: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


class MixtureLinear(nn.Module):
    """``E`` linear experts run together and mixed by per-sample weights ``alpha [B, E]``."""

    def __init__(self, inputs: int, outputs: int, experts: int) -> None:
        super().__init__()
        self.experts, self.outputs = experts, outputs
        layer = nn.Linear(inputs, outputs * experts)  # default init per expert fan-in
        self.weight = nn.Parameter(layer.weight.detach().T.contiguous())  # [in, E*out]
        self.bias = nn.Parameter(layer.bias.detach().clone())

    def forward(self, x: Tensor, alpha: Tensor) -> Tensor:
        y = torch.addmm(self.bias, x, self.weight).view(x.shape[0], self.experts, self.outputs)
        return torch.bmm(alpha.unsqueeze(1), y).squeeze(1)


class ManifoldDecoder(nn.Module):
    """``(state, root motion, z, next phase) -> (joint velocities [B, J, 3], 6D deltas [B, J, 6])``."""

    def __init__(self, config: ManifoldConfig) -> None:
        super().__init__()
        c = config
        self.config = c
        d = state_dim(c.joints)
        cond = d + 3 + 6
        self.gate = nn.Sequential(
            nn.Linear(2 * c.phases + c.latent, c.gate_hidden), nn.ELU(),
            nn.Linear(c.gate_hidden, c.gate_hidden), nn.ELU(), nn.Linear(c.gate_hidden, c.experts),
        )
        self.l1 = MixtureLinear(cond + c.latent, c.hidden, c.experts)
        self.l2 = MixtureLinear(c.hidden + c.latent, c.hidden, c.experts)
        self.l3 = MixtureLinear(c.hidden, c.joints * 9, c.experts)
        self.act = nn.ELU()

    def forward(self, state_vec: Tensor, root_velocity: Tensor, root_rot6d: Tensor, z: Tensor,
                phase: Tensor) -> tuple[Tensor, Tensor]:
        alpha = torch.softmax(self.gate(torch.cat([phase.flatten(1), z], dim=-1)), dim=-1)
        h = self.act(self.l1(torch.cat([state_vec, root_velocity, root_rot6d, z], dim=-1), alpha))
        h = self.act(self.l2(torch.cat([h, z], dim=-1), alpha))
        out = self.l3(h, alpha)
        j = self.config.joints
        return out[:, : j * 3].view(-1, j, 3), out[:, j * 3 :].view(-1, j, 6)

    def step(self, state: PoseState, root_velocity: Tensor, root_rot6d: Tensor, z: Tensor, phase: Tensor) -> PoseState:
        """The next pose state; the root's velocity and rotation are imposed, not predicted."""
        vel, drot = self(state.vector(), root_velocity, root_rot6d, z, phase)
        r = self.config.root
        vel = torch.cat([vel[:, :r], root_velocity.unsqueeze(1), vel[:, r + 1 :]], dim=1)
        return integrate(state, vel, drot, root=r, root_rotation=root_rot6d)


class ManifoldEncoder(nn.Module):
    """Training-only encoder ``q(z | s_t, s_{t+1})`` returning ``(mu, logvar)`` ``[B, latent]``."""

    def __init__(self, config: ManifoldConfig) -> None:
        super().__init__()
        d = state_dim(config.joints)
        h = config.encoder_hidden
        self.net = nn.Sequential(
            nn.Linear(2 * d, h), nn.ELU(), nn.Linear(h, h), nn.ELU(), nn.Linear(h, 2 * config.latent)
        )

    def forward(self, current: Tensor, nxt: Tensor) -> tuple[Tensor, Tensor]:
        mu, logvar = self.net(torch.cat([current, nxt], dim=-1)).chunk(2, dim=-1)
        return mu, logvar.clamp(-10.0, 10.0)


class MotionManifold(nn.Module):
    """Encoder + decoder; only the decoder ships in a bundle."""

    def __init__(self, config: ManifoldConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = ManifoldEncoder(config)
        self.decoder = ManifoldDecoder(config)

"""Root steering: keep the network's character on course for the place it was asked to arrive at.

The network learns to approach the target, and misses it where the request is far from anything in
its training (a target twice as far, half the time, behind it). Steering is a causal correction
inside the recurrent loop, in the transition's canonical frame, frame by frame:

* after each step, the root's ground point ``p`` (``r`` frames before arrival, moving ``v`` per
  frame) is predicted to end at ``p + m r v`` (``m``: ``momentum``, how much of its current speed
  the character is expected to keep);
* the predicted miss, spread over the frames left, ``miss / (r + 1)``, moves the whole body
  (weighted by exact arrival's smoothstep, :func:`model.inference.arrival.arrival_weight`: 0 more
  than ``window`` frames before arrival, 1 on it);
* the shift is written into the sampler's own state (root position and every joint's velocity), so
  the next step sees where the character now is and how fast it went, and its gait follows.

Steering the facing the same way was tried and dropped: the pelvis sways with every step, so its
turning rate is a poor predictor, and on validation it cost more at the plain 40-frame gap than it
won on turned targets (docs/experiments/2026-11-25-steering.md).

A body moved under planted feet would slide them; the engine's foot lock holds them. Each frame's
shift is capped (``max_step_cm``) so a correction never reads as a teleport.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch

from model.inference.arrival import arrival_weight
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerState

Tensor = torch.Tensor


@dataclass(frozen=True)
class SteeringConfig:
    """``window``: frames before arrival over which steering fades in (0: off); ``momentum``: the share of
    its current velocity the character is predicted to keep to the end; ``max_step_cm``: the largest
    shift of one frame."""

    window: int = 0
    momentum: float = 1.0
    max_step_cm: float = 10.0

    def __post_init__(self) -> None:
        if self.window < 0:
            raise ValueError(f"the steering window must be 0 (off) or more frames, got {self.window}")
        if not 0.0 <= self.momentum <= 1.0:
            raise ValueError(f"steering momentum must be in [0, 1], got {self.momentum}")
        if self.max_step_cm <= 0:
            raise ValueError(f"the steering step cap must be positive, got {self.max_step_cm}")

    @property
    def on(self) -> bool:
        return self.window > 0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SteeringConfig:
        unknown = set(data) - {"window", "momentum", "max_step_cm"}
        if unknown:
            raise ValueError(f"unknown steering settings: {', '.join(sorted(unknown))}")
        return cls(**data)


def steering_shift(state: SamplerState, root: int, config: SteeringConfig) -> Tensor:
    """The ground shift ``[N, 2]`` (x, z in the canonical frame) steering gives each row of ``state``,
    a state just stepped (its ``tta`` counts the frames after the one it holds)."""
    pose = state.pose
    remaining = state.tta.float().clamp_min(0.0).unsqueeze(-1)
    velocity = pose.vel[:, root, ::2]  # x, z
    goal = state.target_pos[:, root, ::2]
    miss = goal - (pose.root_xz + config.momentum * remaining * velocity)
    shift = arrival_weight(state.tta, config.window).unsqueeze(-1) * miss / (remaining + 1.0)
    norm = shift.norm(dim=-1, keepdim=True)
    return shift * (config.max_step_cm / norm.clamp_min(config.max_step_cm))


def shifted(state: SamplerState, shift: Tensor) -> SamplerState:
    """``state`` with every row's body moved on the ground by ``shift [N, 2]`` (positions and velocities)."""
    pose = state.pose
    ground = torch.stack([shift[:, 0], torch.zeros_like(shift[:, 0]), shift[:, 1]], dim=-1)
    moved = PoseState(pose.rel, pose.vel + ground.unsqueeze(1), pose.rot, pose.root_xz + shift)
    return SamplerState(state.h, state.c, moved, state.phase, state.target_vec, state.target_pos, state.target_rot,
                        state.target_emb, state.tta, state.noise)


def steer(state: SamplerState, root: int, config: SteeringConfig) -> tuple[SamplerState, Tensor]:
    """``state`` with every row's body moved by :func:`steering_shift` (positions and velocities), and
    that shift ``[N, 2]``."""
    shift = steering_shift(state, root, config)
    return shifted(state, shift), shift

"""Root steering: keep the network's character on course for the place it was asked to arrive at.

The network learns to approach the target, and misses it where the request is far from anything in
its training (a target twice as far, half the time, behind it). Steering is a causal correction
inside the recurrent loop, in the transition's canonical frame, frame by frame:

* after each step, the root's ground point ``p`` (``r`` frames before arrival, moving ``v`` per
  frame) is predicted to end at ``p + m r v`` (``m``: ``momentum``, how much of its current speed
  the character is expected to keep);
* the predicted miss, spread over the frames left, ``miss / (r + 1)``, moves the whole body
  (weighted by exact arrival's smoothstep, :func:`model.inference.output.arrival.arrival_weight`: 0 more
  than ``window`` frames before arrival, 1 on it);
* the shift is written into the sampler's own state (root position and every joint's velocity), so
  the next step sees where the character now is and how fast it went, and its gait follows.

Over the last few frames the root's other two free settings are brought home the same way, with
no prediction (what is left of the miss spread over the frames left, smoothstep-weighted):

* its **facing** (``turn_window``): the whole body turns about the root's vertical toward the
  target's facing, measured from the hips and shoulders the frame's global rotations place
  (:class:`model.motion.features.FacingChains`), at most ``max_turn_deg`` a frame. A long window,
  or one that extrapolates the turning rate, was tried and lost: the pelvis sways with every step,
  and the network turns part of it back (docs/experiments/2026-11-25-steering.md and
  docs/experiments/2026-11-26-facing-height.md);
* its **height** (``height_window``): the whole body moves up or down toward the target root's
  height, at most ``max_rise_cm`` a frame.

A character given a new target mid-stream had less time to face it: from that retarget on, its
facing is finished over ``retarget_turn_window`` frames at most ``retarget_max_turn_deg`` a frame
(0: as any other character). Only rows flagged ``late`` take these settings, so a request without
a retarget is unchanged (docs/experiments/2026-11-27-retarget-facing.md).

A body moved under planted feet would slide them; the engine's foot lock holds them. Each frame's
shift is capped (``max_step_cm``) so a correction never reads as a teleport.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import TypeVar

import torch

from model.inference.output.arrival import arrival_weight
from model.motion.features import FacingChains
from model.motion.rotations import quat_rotate, yaw_quat
from model.nets.pose_state import GROUND_TO_3D, PoseState
from model.nets.transition_net import NetState

Tensor = torch.Tensor
S = TypeVar("S", bound=NetState)
RETARGETED = "retargeted"  # the batch column of the rows retargeted mid-stream (``late``: the retarget window)


@dataclass(frozen=True)
class SteeringConfig:
    """``window``: frames before arrival over which the root's ground position is steered (0: off);
    ``momentum``: the share of its current velocity the character is predicted to keep to the end;
    ``max_step_cm``: the largest ground shift of one frame. ``turn_window`` / ``max_turn_deg``: the
    same for the facing (0: off; degrees a frame); ``height_window`` / ``max_rise_cm``: for the root's
    height (0: off; cm a frame); ``retarget_turn_window`` / ``retarget_max_turn_deg``: the facing's
    window and cap for a character retargeted mid-stream (0: the same as the others). Settings saved
    before a part existed load with it off."""

    window: int = 0
    momentum: float = 1.0
    max_step_cm: float = 10.0
    turn_window: int = 0
    max_turn_deg: float = 4.0
    height_window: int = 0
    max_rise_cm: float = 2.0
    retarget_turn_window: int = 0
    retarget_max_turn_deg: float = 4.0

    def __post_init__(self) -> None:
        for name in ("window", "turn_window", "height_window", "retarget_turn_window"):
            if getattr(self, name) < 0:
                raise ValueError(f"the steering {name.replace('_', ' ')} must be 0 (off) or more frames, "
                                 f"got {getattr(self, name)}")
        if not 0.0 <= self.momentum <= 1.0:
            raise ValueError(f"steering momentum must be in [0, 1], got {self.momentum}")
        for name in ("max_step_cm", "max_turn_deg", "max_rise_cm", "retarget_max_turn_deg"):
            if getattr(self, name) <= 0:
                raise ValueError(f"the steering cap {name} must be positive, got {getattr(self, name)}")

    @property
    def on(self) -> bool:
        return self.window > 0 or self.turn_window > 0 or self.height_window > 0 or self.retarget_turn_window > 0

    @property
    def turns(self) -> bool:
        """Whether any row's facing is steered (which needs the skeleton's facing chains)."""
        return self.turn_window > 0 or self.retarget_turn_window > 0

    def with_window(self, window: int) -> SteeringConfig:
        """These settings with the ground window ``window``; 0 switches every part off (the network alone)."""
        if window == 0:
            return replace(self, window=0, turn_window=0, height_window=0, retarget_turn_window=0)
        return replace(self, window=int(window))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SteeringConfig:
        unknown = set(data) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown steering settings: {', '.join(sorted(unknown))}")
        return cls(**data)


_UP = torch.tensor([0.0, 1.0, 0.0])


def steering_shift(state: NetState, root: int, config: SteeringConfig) -> Tensor:
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


def shifted(state: S, shift: Tensor) -> S:
    """``state`` with every row's body moved on the ground by ``shift [N, 2]`` (positions and velocities)."""
    pose = state.pose
    ground = shift @ GROUND_TO_3D  # (x, 0, z)
    return replace(state, pose=PoseState(pose.rel, pose.vel + ground.unsqueeze(1), pose.rot, pose.root_xz + shift))  # type: ignore[type-var]


def _spread(miss: Tensor, tta: Tensor, window: int | Tensor, cap: float | Tensor) -> Tensor:
    """What is left of ``miss [N]`` spread over the frames left, smoothstep-weighted, capped at ``cap``
    (window and cap: one for every row, or ``[N]``; a window of 0 moves nothing)."""
    remaining = tta.float().clamp_min(0.0)
    if isinstance(window, Tensor):
        weight = torch.where(window > 0, arrival_weight(tta, window.clamp_min(1)), torch.zeros_like(remaining))
    else:
        weight = arrival_weight(tta, window) if window > 0 else torch.zeros_like(remaining)
    spread = weight * miss / (remaining + 1.0)
    if isinstance(cap, Tensor):
        return torch.minimum(torch.maximum(spread, -cap), cap)
    return spread.clamp(-cap, cap)


def finishing_turn(state: NetState, config: SteeringConfig, facing: FacingChains,
                   late: Tensor | None = None) -> Tensor:
    """The turn ``[N]`` (radians about +Y) steering gives each row's facing this frame; rows where ``late
    [N]`` (bool) is set were retargeted mid-stream and take the retarget window and cap where those are on."""
    yaw = facing.yaw(torch.cat([state.target_rot, state.pose.rot]))  # both in one pass
    n = state.pose.rot.shape[0]
    miss = yaw[:n] - yaw[n:]
    miss = torch.atan2(torch.sin(miss), torch.cos(miss))  # the short way round
    cap = math.radians(config.max_turn_deg)
    if late is None or config.retarget_turn_window == 0:
        return _spread(miss, state.tta, config.turn_window, cap)
    window = torch.where(late, torch.tensor(config.retarget_turn_window), torch.tensor(config.turn_window))
    caps = torch.where(late, torch.tensor(math.radians(config.retarget_max_turn_deg)), torch.tensor(cap))
    return _spread(miss, state.tta, window, caps)


def finishing_rise(state: NetState, root: int, config: SteeringConfig) -> Tensor:
    """The vertical shift ``[N]`` (cm) steering gives each row's body this frame."""
    miss = state.target_pos[:, root, 1] - state.pose.rel[:, root, 1]
    return _spread(miss, state.tta, config.height_window, config.max_rise_cm)


def turned_and_raised(state: S, turn: Tensor | None, rise: Tensor | None) -> S:
    """``state`` with every row's body turned about its root's vertical by ``turn [N]`` (positions,
    velocities and rotations turn together, as if it had always faced that way) and moved up by
    ``rise [N]`` (a displacement: the velocities take it)."""
    pose = state.pose
    rel, vel, rot = pose.rel, pose.vel, pose.rot
    if turn is not None:  # one turn of every 3-vector of the pose: positions, velocities, both rotation columns
        vectors = torch.cat([rel, vel, rot[..., :3], rot[..., 3:]], dim=-2)
        rel, vel, c1, c2 = quat_rotate(yaw_quat(turn).unsqueeze(-2), vectors).chunk(4, dim=-2)
        rot = torch.cat([c1, c2], dim=-1)
    if rise is not None:
        up = (rise.unsqueeze(-1) * _UP).unsqueeze(1)  # (0, rise, 0)
        rel, vel = rel + up, vel + up
    return replace(state, pose=PoseState(rel, vel, rot, pose.root_xz))  # type: ignore[type-var]


def steer(state: S, root: int, config: SteeringConfig, facing: FacingChains | None = None,
          late: Tensor | None = None) -> tuple[S, Tensor]:
    """``state`` with every row's body moved by :func:`steering_shift` (positions and velocities), then
    turned and raised where those parts are on, and the ground shift ``[N, 2]`` (zero where the ground
    part is off). Turning needs ``facing``; ``late [N]`` (bool) flags the rows retargeted mid-stream."""
    if config.window > 0:
        shift = steering_shift(state, root, config)
        state = shifted(state, shift)
    else:
        shift = torch.zeros_like(state.pose.root_xz)
    turn = rise = None
    if config.turns:
        if facing is None:
            raise ValueError("steering the facing needs the skeleton's facing chains")
        turn = finishing_turn(state, config, facing, late)
    if config.height_window > 0:
        rise = finishing_rise(state, root, config)
    if turn is not None or rise is not None:
        state = turned_and_raised(state, turn, rise)
    return state, shift

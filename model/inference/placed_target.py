"""A target given as a place and a facing (``target_at``): the engine picks the pose to arrive in.

A game often knows where a character should end up and which way it should face, not a whole pose. The
pose chosen is the context's own last pose (the character as it is now), turned about the vertical through
its root so that it faces ``yaw`` and moved so that its root stands over ``(x, z)``, its height kept, as a
one-frame target. The facing is the model's own (:func:`model.motion.features.facing_yaw`:
up x (right - left) of the hips and shoulders), the one the web viewer uses when a target is placed on the
ground, so "face this way" means the same to the caller, the viewer and the network.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from model.motion.clip import Clip
from model.motion.features import facing_yaw
from model.motion.rotations import quat_mul, yaw_quat


@dataclass(frozen=True)
class Placement:
    """Where to arrive: ``x``, ``z`` the root's ground position (model units, +Y up) and ``yaw_deg`` the facing
    in degrees about +Y (0 faces +Z, 90 faces +X)."""

    x: float
    z: float
    yaw_deg: float

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.x, self.z, self.yaw_deg)):
            raise ValueError(f"a placement needs finite x, z and yaw, got {self.x}, {self.z}, {self.yaw_deg}")


def pose_facing(clip: Clip, frame: int = -1) -> float:
    """The facing (radians about +Y, 0 = +Z) of one frame of ``clip``, as the model measures it."""
    positions = clip.window(frame % clip.num_frames, frame % clip.num_frames + 1).global_positions()[0]
    return float(facing_yaw(positions.double(), clip.skeleton))


def placed_target(context: Clip, place: Placement) -> Clip:
    """The one-frame target of ``place``: ``context``'s last pose turned to its facing and moved to its ground
    position (see the module doc)."""
    last = context.window(context.num_frames - 1, context.num_frames)
    turn = yaw_quat(torch.tensor(math.radians(place.yaw_deg) - pose_facing(last), dtype=torch.float64))
    rotations = last.rotations.clone()
    rotations[:, 0] = quat_mul(turn.to(rotations.dtype), rotations[:, 0])
    roots = last.root_positions.clone()
    roots[:, 0], roots[:, 2] = place.x, place.z
    # Turned about the vertical through its own root, the body swings round the root: only the root's rotation
    # changes, and the facing by exactly the turn.
    return Clip(skeleton=last.skeleton, rotations=rotations, root_positions=roots, fps=last.fps,
                name=f"target_at({place.x:g}, {place.z:g}, {place.yaw_deg:g})")

"""Whether a target can be reached in the time asked at the style's capture speed, and what the answer says if not.

The engine keeps the root's horizontal speed within the style's capture maximum
(:mod:`model.inference.output.speed_cap`, limits from :mod:`model.motion.gait_limits`), so a target farther
than that speed covers in the frames asked is not reached: the character arrives short rather than glide.
:class:`Reach` is the notice: worked out when a transition starts and again whenever it is retargeted, from
where the root then stands to where the target's root stands (on the ground).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

TOLERANCE_CM = 1.0  # a distance this much over what the speed covers still counts as reachable (rounding)


@dataclass(frozen=True)
class Reach:
    """``distance_cm``: from the root's ground point to the target root's; ``frames``: the frames asked for it;
    ``max_speed_cm_s``: the style's capture maximum; ``reachable_cm``: the most the root covers in ``frames``
    at that speed; ``needed_frames``: the frames the distance takes at that speed; ``feasible``: whether the
    distance is within reach."""

    feasible: bool
    distance_cm: float
    frames: int
    needed_frames: int
    reachable_cm: float
    max_speed_cm_s: float

    def to_dict(self) -> dict[str, Any]:
        return {"feasible": self.feasible, "distance_cm": round(self.distance_cm, 1), "frames": self.frames,
                "needed_frames": self.needed_frames, "reachable_cm": round(self.reachable_cm, 1),
                "max_speed_cm_s": round(self.max_speed_cm_s, 1)}


def reach_of(distance_cm: float, frames: int, max_speed_cm_s: float, fps: float) -> Reach:
    """The notice for a root ``distance_cm`` from its target with ``frames`` frames to go at ``max_speed_cm_s``."""
    per_frame = max_speed_cm_s / fps
    reachable = per_frame * frames
    needed = max(1, math.ceil(max(0.0, distance_cm - TOLERANCE_CM) / per_frame))
    return Reach(distance_cm <= reachable + TOLERANCE_CM, distance_cm, frames, needed, reachable, max_speed_cm_s)


def ground_distance(root_xz: torch.Tensor, target_pos: torch.Tensor, root: int) -> float:
    """The ground distance (cm) from a state's root ``root_xz [1, 2]`` to its target's root (``target_pos
    [1, J, 3]``), both in the transition's canonical frame."""
    return float((target_pos[0, root, ::2] - root_xz[0]).norm())

"""When a foot counts as planted, and how high the capture's planted feet stand: what the foot plant keeps.

A foot is *planted* while its ankle moves slower than :data:`PLANTED_CM_S` over the ground (1 cm a frame at
30 fps); from :data:`FREE_CM_S` on (the foot lock's plant speed) it is free. Judged by the foot's own speed,
this needs no contact label and holds on any rig. :func:`planted_rise` measures a take: the most a planted
foot's lowest joint stands above the lowest any foot joint reaches in the take (its floor). The capture's
figure per style (:mod:`model.motion.gait_limits`) is how high the engine lets a planted foot stand
(:mod:`model.inference.output.foot_plant`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

Tensor = torch.Tensor

PLANTED_CM_S = 30.0  # ankle ground speed under which a foot is planted
FREE_CM_S = 60.0  # ankle ground speed from which a foot is free (the foot lock's plant speed)


def planted_weight(speed_cm_s: Tensor) -> Tensor:
    """How planted feet moving at ``speed_cm_s`` are: 1 under :data:`PLANTED_CM_S`, 0 from :data:`FREE_CM_S`,
    smooth between (so a foot eases in and out of its plant)."""
    x = ((FREE_CM_S - speed_cm_s) / (FREE_CM_S - PLANTED_CM_S)).clamp(0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def planted_rise(positions: Tensor, feet: Sequence[Sequence[int]], fps: float) -> float:
    """The most a planted foot's lowest joint stands above the take's floor (cm), for world joint ``positions
    [T, J, 3]`` (Y up) at ``fps`` and ``feet``: each foot's joints, ankle first; 0 for a take without a planted
    frame or shorter than two frames."""
    if positions.shape[0] < 2:
        return 0.0
    floor = positions[:, [j for foot in feet for j in foot], 1].min()
    most = 0.0
    for foot in feet:
        ankle = positions[:, foot[0]]
        speed = (ankle[1:] - ankle[:-1])[:, [0, 2]].norm(dim=-1) * fps
        lowest = positions[1:, list(foot), 1].amin(dim=-1)
        planted = lowest[speed < PLANTED_CM_S]
        if len(planted):
            most = max(most, float(planted.max() - floor))
    return most

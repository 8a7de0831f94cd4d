"""The speed cap: no frame moves the root faster on the ground than the style's capture ever did.

Runs in the recurrent loop, after the network's step and root steering (:mod:`model.inference.output.steering`),
per character: where the root's ground step this frame (the network's own and steering's together) is longer
than the character's cap (its style's capture maximum, :mod:`model.motion.gait_limits`, in cm a frame), the
whole body is moved back along that step until it is not, in the sampler's own state (positions and
velocities), so the next step starts from where the character now is. The pull-back is added to the ground
shift steering reports, so the stride warp and the foot lock after it treat it as carried motion: a planted
foot stays planted and the character arrives late or short instead of gliding. A cap of ``inf`` leaves a row
as it is (a bundle without gait limits).
"""

from __future__ import annotations

from typing import TypeVar

import torch

from model.inference.output.steering import shifted
from model.nets.transition_net import NetState

Tensor = torch.Tensor
S = TypeVar("S", bound=NetState)


def speed_capped(before_xz: Tensor, state: S, shift: Tensor | None,
                 cap: Tensor) -> tuple[S, Tensor | None]:
    """``state`` (just stepped from a root at ``before_xz [N, 2]``) with each row's ground step held within
    ``cap [N]`` (cm/frame), and steering's ``shift [N, 2]`` with the pull-back added (None stays None where no
    row was pulled back)."""
    step = state.pose.root_xz - before_xz
    norm = step.norm(dim=-1)
    over = norm > cap
    if not bool(over.any()):
        return state, shift
    scale = torch.where(over, cap / norm.clamp_min(1e-6), torch.ones_like(norm))
    back = step * (scale - 1.0).unsqueeze(-1)
    return shifted(state, back), back if shift is None else shift + back

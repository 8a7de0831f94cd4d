"""The speed cap: no frame moves the root faster on the ground than the style's capture ever did.

Runs in the recurrent loop, after the network's step and root steering (:mod:`model.inference.output.steering`),
per character: where the root's ground step this frame (the network's own and steering's together) is longer
than the character's cap (its style's capture maximum, :mod:`model.motion.gait_limits`, in cm a frame), the
whole body is moved back along that step until it is not, in the sampler's own state (positions and
velocities), so the next step starts from where the character now is. The pull-back is added to the ground
shift steering reports, so the stride warp and the foot lock after it treat it as carried motion: a planted
foot stays planted and the character arrives late or short instead of gliding. A cap of ``inf`` leaves a row
as it is (a bundle without gait limits).

The cap alone would let a character that walks slower than its target needs fall behind until the target is out
of reach (the network's own arrival walked well under the cap for half a transition, then met the cap and fell
short). :func:`kept_in_reach` runs after it: where a row's target is farther than the cap covers in the frames
left, its step is bent toward the target (never longer than the cap) until it is not, so a target within reach
when the transition starts is still within reach on every frame, and is reached. Rows that keep their target
within reach are left as they are, and so is every row where ground steering is off (the network alone).
"""

from __future__ import annotations

from typing import TypeVar

import torch

from model.inference.output.arrival import capped_root
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


def kept_in_reach(before_xz: Tensor, state: S, shift: Tensor | None, cap: Tensor,
                  root: int) -> tuple[S, Tensor | None]:
    """``state`` (stepped from ``before_xz [N, 2]`` and held within ``cap [N]``) with each row whose target root
    (``state.target_pos``, joint ``root``) is farther than ``cap`` times its frames left moved along on the ground
    to the nearest point that is within both (:func:`model.inference.output.arrival.capped_root`), and
    ``shift`` with that move added (None stays None where no row moved)."""
    here = state.pose.root_xz
    goal = state.target_pos[:, root, ::2]
    left = state.tta.clamp_min(0).to(here.dtype)
    behind = ((goal - here).norm(dim=-1) > cap * left) & torch.isfinite(cap)
    if not bool(behind.any()):
        return state, shift
    move = torch.zeros_like(here)
    for i in torch.nonzero(behind).flatten().tolist():
        placed = capped_root(here[i], before_xz[i], goal[i], float(cap[i]), int(left[i]))
        move[i] = placed - here[i]
    return shifted(state, move), move if shift is None else shift + move

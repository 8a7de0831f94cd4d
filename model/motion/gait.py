"""Gait measures on global joint positions: toe foot skate, the backward share, airborne runs, toe rest height.

All take positions ``[B, T, J, 3]`` in cm, Y up, frame 0 first (for a transition: the last context
frame, then the generated frames), at the clip rate.

* **toe foot skate** (cm/frame): on the two toe joints only, each toe's horizontal displacement
  between frames ``t-1`` and ``t`` weighted by ``clamp(2 - 2^(h/H), 0, 1)``, ``h`` the toe's height
  above its rest height at ``t`` and ``H = 2.5`` cm; pooled as the weighted sum over the number of
  samples with a non-zero weight. Ankles are left out: a real ankle rolls over a planted toe, so a
  ground per ankle counts that roll as skate and flatters a sliding foot by comparison.
* **backward share**: of the frame steps whose hips move faster than 30 cm/s horizontally, the share
  that move against the body's facing (hips velocity . facing < 0); NaN where no step is that fast.
* **airborne run**: the longest run of consecutive frames with both toes more than 15 cm above rest.
* **toe rest height**: the height a take's toes have when planted (the 5th percentile of the lower
  toe's height over the take's frames).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.motion.features import facing_directions
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

TOE_REST_CM = 4.25
"""The toes' rest height above y = 0 on the Bandai-Namco rig (both data sets, measured)."""
CONTACT_HEIGHT_CM = 2.5
MOVING_CM_S = 30.0
AIRBORNE_CM = 15.0


def toe_joints(skeleton: Skeleton) -> tuple[int, int]:
    """The left and right toe joints (the last contact joint of each foot)."""
    return skeleton.roles.left_foot[-1], skeleton.roles.right_foot[-1]


def _rest(rest: float | Tensor, pos: Tensor) -> Tensor:
    """Rest height broadcast to ``[B, 1, 1]`` (a number, ``[B]`` or ``[B, 2]`` per toe -> ``[B, 1, 2]``)."""
    r = torch.as_tensor(rest, dtype=pos.dtype, device=pos.device)
    if r.dim() == 0:
        return r.reshape(1, 1, 1)
    return r.reshape(r.shape[0], 1, -1)


def _check(pos: Tensor) -> None:
    if pos.dim() != 4 or pos.shape[-1] != 3:
        raise ValueError(f"positions must be [B, T, J, 3], got {list(pos.shape)}")


def toe_skate_terms(pos: Tensor, toes: Sequence[int], rest: float | Tensor = TOE_REST_CM,
                    height_cm: float = CONTACT_HEIGHT_CM) -> tuple[Tensor, Tensor]:
    """``(sum of v * w, number of toe samples with w > 0)``: pool batches by summing both."""
    _check(pos)
    p = pos[:, :, list(toes)]  # [B, T, 2, 3]
    if p.shape[1] < 2:
        zero = torch.zeros((), dtype=pos.dtype, device=pos.device)
        return zero, zero.clone()
    v = (p[:, 1:] - p[:, :-1])[..., [0, 2]].norm(dim=-1)  # [B, T-1, 2] horizontal cm/frame
    h = p[:, 1:, :, 1] - _rest(rest, pos)
    w = (2.0 - torch.pow(2.0, h / height_cm)).clamp(0.0, 1.0)
    return (v * w).sum(), (w > 0).sum().to(pos.dtype)


def toe_skate(pos: Tensor, toes: Sequence[int], rest: float | Tensor = TOE_REST_CM,
              height_cm: float = CONTACT_HEIGHT_CM) -> Tensor:
    """Toe foot skate in cm/frame over the batch (see the module docstring); 0 when no toe is that low."""
    total, count = toe_skate_terms(pos, toes, rest, height_cm)
    return total / count.clamp_min(1.0)


def backward_share(pos: Tensor, skeleton: Skeleton, fps: float, min_speed_cm_s: float = MOVING_CM_S) -> Tensor:
    """``[B]`` the share of fast hip steps that go against the facing (NaN where none is fast)."""
    _check(pos)
    if pos.shape[1] < 2:
        return torch.full((pos.shape[0],), float("nan"), dtype=pos.dtype)
    hips = pos[:, :, skeleton.roles.root]
    step = (hips[:, 1:] - hips[:, :-1])[..., [0, 2]]  # [B, T-1, 2] (x, z)
    facing = facing_directions(pos[:, 1:], skeleton)[..., [0, 2]]  # at the later frame
    fast = step.norm(dim=-1) * fps > min_speed_cm_s
    against = (step * facing).sum(-1) < 0
    n = fast.sum(1).to(pos.dtype)
    share = (fast & against).sum(1).to(pos.dtype) / n.clamp_min(1.0)
    return torch.where(n > 0, share, torch.full_like(share, float("nan")))


def longest_airborne(pos: Tensor, toes: Sequence[int], rest: float | Tensor = TOE_REST_CM,
                     above_cm: float = AIRBORNE_CM) -> Tensor:
    """``[B]`` the longest run of frames (integer-valued) with both toes more than ``above_cm`` above rest."""
    _check(pos)
    h = pos[:, :, list(toes), 1] - _rest(rest, pos)  # [B, T, 2]
    up = (h > above_cm).all(-1)  # [B, T]
    run = torch.zeros(pos.shape[0], dtype=torch.long)
    best = torch.zeros_like(run)
    for t in range(up.shape[1]):
        run = torch.where(up[:, t], run + 1, torch.zeros_like(run))
        best = torch.maximum(best, run)
    return best

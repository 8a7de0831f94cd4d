"""Feet through the floor: how far the foot joints go below their ground level.

Foot skate (:func:`model.evaluation.metrics.foot_skate`) scores feet sliding on the floor; nothing
there sees a body that sinks, feet and all, into it (as the default model's walks to a target behind
the character did: the toes 8-10 cm under the floor). Each foot joint's ground level is the same as
foot skate's (:func:`model.evaluation.metrics.ground_levels`, a low percentile of the data), so real
motion goes a little below it too; the report gives the ground truth's figure for scale.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

Tensor = torch.Tensor


def floor_depth(pos: Tensor, feet: Sequence[int], ground: Tensor | Sequence[float]) -> Tensor:
    """Per sequence, the deepest any foot joint goes below its ground level, in cm (0: never below).

    Args:
        pos: ``[B, T, J, 3]`` positions in cm, Y up.
        feet: indices of the foot joints.
        ground: ``[len(feet)]`` ground level of each foot joint in cm.

    Returns:
        ``[B]`` depths, at least 0.
    """
    idx = list(feet)
    ground_t = torch.as_tensor(ground, dtype=pos.dtype, device=pos.device).reshape(-1)
    if ground_t.numel() != len(idx):
        raise ValueError(f"ground has {ground_t.numel()} levels for {len(idx)} foot joints")
    if pos.ndim != 4 or pos.shape[1] == 0:
        raise ValueError(f"need positions [B, T, J, 3] with at least one frame, got {list(pos.shape)}")
    below = ground_t - pos[:, :, idx, 1]  # [B, T, F]
    return below.flatten(1).amax(dim=1).clamp_min(0.0)

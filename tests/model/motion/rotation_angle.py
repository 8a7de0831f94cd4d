"""The angle between two rotations, which the tests compare poses by (the model itself never needs it)."""

from __future__ import annotations

import torch

from model.motion.rotations import quat_conjugate, quat_mul, quat_normalize


def quat_angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle in radians between rotations ``a`` and ``b`` (sign-invariant), shape ``(...)``.

    Computed as ``2 atan2(|v|, |w|)`` of the relative rotation, which stays accurate for tiny
    angles where ``acos`` of a dot product loses everything in float32.
    """
    rel = quat_mul(quat_conjugate(quat_normalize(a)), quat_normalize(b))
    return 2.0 * torch.atan2(rel[..., :3].norm(dim=-1), rel[..., 3].abs())

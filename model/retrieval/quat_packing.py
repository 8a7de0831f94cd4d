"""Unit quaternions in 32 bits: the "smallest three" packing.

A unit quaternion is known from any three of its components, and its largest component (in magnitude) is at least
1/2, so the other three lie in [-1/sqrt(2), 1/sqrt(2)]. Packed: the largest's index in 2 bits, then the three others,
each in 10 bits over that range, with the sign chosen so the largest is positive (q and -q are one rotation). Each
of the three is off by at most half a step, 1/sqrt(2)/1023, about 0.0007: the rotation is within 0.3 degree.
"""

from __future__ import annotations

import math

import torch

from model.motion.rotations import quat_normalize

Tensor = torch.Tensor
BITS = 10
_LEVELS = (1 << BITS) - 1
_RANGE = 1.0 / math.sqrt(2.0)
# For each index of the largest component, the indices of the other three, in order.
_OTHERS = torch.tensor([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def pack_quaternions(q: Tensor) -> Tensor:
    """Unit quaternions ``[..., 4]`` (x, y, z, w) to int32 ``[...]``."""
    q = quat_normalize(q.double())
    largest = q.abs().argmax(-1)
    q = q * torch.where(q.gather(-1, largest.unsqueeze(-1)) < 0, -1.0, 1.0)
    three = q.gather(-1, _OTHERS[largest])  # [..., 3]
    levels = torch.round((three.clamp(-_RANGE, _RANGE) + _RANGE) / (2 * _RANGE) * _LEVELS).long()
    packed = (largest << (3 * BITS)) | (levels[..., 0] << (2 * BITS)) | (levels[..., 1] << BITS) | levels[..., 2]
    return torch.where(packed >= 1 << 31, packed - (1 << 32), packed).to(torch.int32)  # the same 32 bits, signed


def unpack_quaternions(packed: Tensor) -> Tensor:
    """int32 ``[...]`` from :func:`pack_quaternions` back to unit quaternions ``[..., 4]`` (float32)."""
    p = packed.long() & 0xFFFFFFFF
    largest = (p >> (3 * BITS)) & 3
    levels = torch.stack([(p >> (2 * BITS)) & _LEVELS, (p >> BITS) & _LEVELS, p & _LEVELS], -1)
    three = levels.double() / _LEVELS * (2 * _RANGE) - _RANGE
    big = (1.0 - three.square().sum(-1)).clamp_min(0.0).sqrt()
    out = torch.zeros(*p.shape, 4, dtype=torch.float64)
    out.scatter_(-1, _OTHERS[largest], three)
    out.scatter_(-1, largest.unsqueeze(-1), big.unsqueeze(-1))
    return quat_normalize(out).float()

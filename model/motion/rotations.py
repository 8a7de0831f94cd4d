"""Rotation representations and conversions between them, batched over leading dimensions.

Glossary, fixed once for the whole project (model, wire format and engine clients alike):

* ``quat``: a unit quaternion stored as ``(..., 4)`` in **x, y, z, w** order. ``q`` and ``-q``
  are the same rotation; functions return whichever sign the maths gives unless they say so.
* ``matrix``: a rotation matrix ``(..., 3, 3)`` acting on column vectors, ``v' = R @ v``.
* ``sixd``: the 6D representation (Zhou et al. 2019), ``(..., 6)``: the first two **columns**
  of the matrix, concatenated. Decoding uses Gram-Schmidt, so any non-degenerate 6-vector maps
  to a valid rotation.
* ``euler``: three angles in **radians**, ``(..., 3)``, listed in the order of an axis string
  such as ``"ZXY"``; the rotation is ``R = R_Z(a0) @ R_X(a1) @ R_Y(a2)`` (intrinsic, the BVH
  convention: channels apply in the order they are listed).
* ``quat_mul(a, b)`` composes ``a`` after ``b``, matching ``matrix(a) @ matrix(b)``.

Everything is plain torch and keeps the input's dtype and device.
"""

from __future__ import annotations

import math

import torch

Tensor = torch.Tensor

_AXES = {"X": 0, "Y": 1, "Z": 2}
_EPS = 1e-8


def quat_identity(shape: tuple[int, ...] = (), dtype: torch.dtype = torch.float32) -> Tensor:
    """Identity quaternions of the given leading ``shape``: ``(*shape, 4)``."""
    q = torch.zeros(*shape, 4, dtype=dtype)
    q[..., 3] = 1.0
    return q


def quat_normalize(q: Tensor) -> Tensor:
    """Scale quaternions to unit length."""
    return q / q.norm(dim=-1, keepdim=True).clamp_min(_EPS)


def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate, which is the inverse for unit quaternions."""
    return torch.cat([-q[..., :3], q[..., 3:]], dim=-1)



# Coefficient of a_i * b_j in component k of the Hamilton product a * b (x, y, z, w), as rows 4i + j.
# One outer product and one small matmul replace 28 scalar-lane multiplies and adds: at batch 1 the
# product is bound by per-operation dispatch, and this form has 3 operations instead of about 30.
_HAMILTON = [
    (3, 0, 0, 1), (0, 3, 0, 1), (1, 2, 0, 1), (2, 1, 0, -1),
    (3, 1, 1, 1), (0, 2, 1, -1), (1, 3, 1, 1), (2, 0, 1, 1),
    (3, 2, 2, 1), (0, 1, 2, 1), (1, 0, 2, -1), (2, 3, 2, 1),
    (3, 3, 3, 1), (0, 0, 3, -1), (1, 1, 3, -1), (2, 2, 3, -1),
]
_HAMILTON_ROWS = [[0.0] * 4 for _ in range(16)]
for _i, _j, _k, _sign in _HAMILTON:
    _HAMILTON_ROWS[4 * _i + _j][_k] = float(_sign)
_hamilton_tables: dict[tuple[torch.dtype, torch.device], Tensor] = {}


def _hamilton_table(dtype: torch.dtype, device: torch.device) -> Tensor:
    table = _hamilton_tables.get((dtype, device))
    if table is None:
        # One tensor from a list (a constant if this first happens while tracing), made outside
        # inference mode: an inference tensor could not be saved for a later backward pass.
        with torch.inference_mode(False):
            table = torch.tensor(_HAMILTON_ROWS, dtype=dtype, device=device)
        _hamilton_tables[(dtype, device)] = table
    return table


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``). Broadcasts."""
    outer = (a.unsqueeze(-1) * b.unsqueeze(-2)).flatten(-2)  # [..., 16]: a_i * b_j at 4i + j
    return outer @ _hamilton_table(outer.dtype, outer.device)


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)``. Broadcasts."""
    qv = q[..., :3]
    w = q[..., 3:]
    t = 2.0 * torch.linalg.cross(qv, v)
    return v + w * t + torch.linalg.cross(qv, t)


def quat_canonical(q: Tensor) -> Tensor:
    """Pick the sign with ``w >= 0`` so equal rotations compare equal."""
    return torch.where(q[..., 3:] < 0, -q, q)


def quat_make_continuous(q: Tensor, dim: int = 0) -> Tensor:
    """Flip signs along ``dim`` (time) so consecutive quaternions have a non-negative dot product.

    Interpolation and finite differences need this; the rotations themselves do not change.
    """
    q = q.movedim(dim, 0)
    dots = (q[1:] * q[:-1]).sum(-1, keepdim=True)
    flips = torch.cumprod(torch.where(dots < 0, -1.0, 1.0).to(q.dtype), dim=0)
    out = torch.cat([q[:1], q[1:] * flips], dim=0)
    return out.movedim(0, dim)


def quat_to_matrix(q: Tensor) -> Tensor:
    """Unit quaternions ``(..., 4)`` to rotation matrices ``(..., 3, 3)``."""
    x, y, z, w = quat_normalize(q).unbind(-1)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    m = torch.stack(
        [
            1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
            2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
            2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
        ],
        dim=-1,
    )
    return m.reshape(*q.shape[:-1], 3, 3)


def _shepperd_candidates(m: Tensor) -> Tensor:
    """The four Shepperd candidates ``[..., 4, 4]`` (rows: w, x, y, z largest; each is 4|c| q)."""
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    return torch.stack(
        [
            torch.stack([m21 - m12, m02 - m20, m10 - m01, 1 + m00 + m11 + m22], dim=-1),
            torch.stack([1 + m00 - m11 - m22, m01 + m10, m02 + m20, m21 - m12], dim=-1),
            torch.stack([m01 + m10, 1 - m00 + m11 - m22, m12 + m21, m02 - m20], dim=-1),
            torch.stack([m02 + m20, m12 + m21, 1 - m00 - m11 + m22, m10 - m01], dim=-1),
        ],
        dim=-2,
    )


# The candidates are affine in the nine entries: one matrix product on [m, 1] computes them all
# (a dozen tiny ops fewer per call, which matters on the per-frame path at batch 1).
_basis = torch.cat([torch.eye(9, dtype=torch.float64).reshape(9, 3, 3), torch.zeros(1, 3, 3, dtype=torch.float64)])
_SHEPPERD = _shepperd_candidates(_basis).reshape(10, 16)
_SHEPPERD[:9] -= _SHEPPERD[9]  # rows 0-8: linear parts; row 9: the constant (all-zero matrix input)
del _basis


def matrix_to_quat(m: Tensor) -> Tensor:
    """Rotation matrices ``(..., 3, 3)`` to unit quaternions ``(..., 4)`` with ``w >= 0``.

    Uses the numerically best of the four Shepperd candidates per element, so it is exact near
    180-degree rotations too.
    """
    flat = torch.cat([m.reshape(*m.shape[:-2], 9), torch.ones_like(m[..., 0, :1])], dim=-1)
    cand = (flat @ _SHEPPERD.to(device=m.device, dtype=m.dtype)).reshape(*m.shape[:-2], 4, 4)  # [..., candidate, (x, y, z, w)]
    # Candidate k's own component (w for k=0, x, y, z for k=1..3) holds 1 + trace-like sums: pick the largest.
    # cand[..., k, (k + 3) % 4] for each k: rolled one column on, the diagonal (cheaper than a list index).
    t = torch.diagonal(cand.roll(1, dims=-1), dim1=-2, dim2=-1)
    # max(...).indices, not argmax: the same first largest index, but argmax over this strided diagonal view
    # took 270 us at 128 characters (22 joints) against 10 us (one thread, 2-core EPYC).
    best = t.max(dim=-1, keepdim=True).indices
    q = torch.gather(cand, -2, best.unsqueeze(-1).expand(*best.shape[:-1], 1, 4)).squeeze(-2)
    return quat_canonical(quat_normalize(q))


def matrix_to_sixd(m: Tensor) -> Tensor:
    """Rotation matrices ``(..., 3, 3)`` to 6D ``(..., 6)``: first column, then second column."""
    return torch.cat([m[..., :, 0], m[..., :, 1]], dim=-1)


def sixd_to_matrix(d: Tensor) -> Tensor:
    """6D ``(..., 6)`` to rotation matrices by Gram-Schmidt on the two columns."""
    a1, a2 = d[..., :3], d[..., 3:]
    b1 = a1 / a1.norm(dim=-1, keepdim=True).clamp_min(_EPS)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / a2.norm(dim=-1, keepdim=True).clamp_min(_EPS)
    b3 = torch.linalg.cross(b1, b2)
    return torch.stack([b1, b2, b3], dim=-1)


def quat_to_sixd(q: Tensor) -> Tensor:
    """Unit quaternions to 6D."""
    return matrix_to_sixd(quat_to_matrix(q))


def sixd_to_quat(d: Tensor) -> Tensor:
    """6D to unit quaternions (``w >= 0``)."""
    return matrix_to_quat(sixd_to_matrix(d))


def sixd_normalize(d: Tensor) -> Tensor:
    """Project 6D vectors back onto valid rotations (Gram-Schmidt, re-encoded)."""
    return matrix_to_sixd(sixd_to_matrix(d))


def axis_angle_to_quat(axis: Tensor, angle: Tensor) -> Tensor:
    """Rotations of ``angle (...)`` radians about unit ``axis (..., 3)``."""
    half = 0.5 * angle.unsqueeze(-1)
    return torch.cat([axis * torch.sin(half), torch.cos(half)], dim=-1)


def _parse_order(order: str) -> tuple[int, int, int]:
    up = order.upper()
    if len(up) != 3 or any(c not in _AXES for c in up) or len(set(up)) != 3:
        raise ValueError(
            f"Euler order {order!r} is not supported: use three distinct axes from X, Y, Z, e.g. 'ZXY'"
        )
    return _AXES[up[0]], _AXES[up[1]], _AXES[up[2]]


def matrix_to_euler(m: Tensor, order: str) -> Tensor:
    """Rotation matrices to Euler angles in radians listed in ``order``.

    The middle angle lies in ``[-pi/2, pi/2]``. At gimbal lock (middle angle at +-90 degrees) the
    last angle is set to 0 and the first one carries the whole rotation about the locked axis.
    """
    i, j, k = _parse_order(order)
    # +1 for cyclic orders (XYZ, YZX, ZXY), -1 for the others.
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    sin_b = (s * m[..., i, k]).clamp(-1.0, 1.0)
    b = torch.asin(sin_b)
    cos_b = torch.sqrt((1.0 - sin_b * sin_b).clamp_min(0.0))
    locked = cos_b < 1e-6
    a = torch.atan2(-s * m[..., j, k], m[..., k, k])
    c = torch.atan2(-s * m[..., i, j], m[..., i, i])
    a_locked = torch.atan2(s * m[..., k, j], m[..., j, j])
    a = torch.where(locked, a_locked, a)
    c = torch.where(locked, torch.zeros_like(c), c)
    return torch.stack([a, b, c], dim=-1)


def euler_to_quat(angles: Tensor, order: str) -> Tensor:
    """Euler angles in radians listed in ``order`` to quaternions."""
    i, j, k = _parse_order(order)
    eye = torch.eye(3, dtype=angles.dtype, device=angles.device)
    # Contiguous angle columns: elementwise ops on strided float64 views ran ~30x slower with 2 threads.
    qs = [axis_angle_to_quat(eye[a].expand(*angles.shape[:-1], 3), angles[..., n].contiguous()) for n, a in enumerate((i, j, k))]
    return quat_mul(quat_mul(qs[0], qs[1]), qs[2])


def quat_to_euler(q: Tensor, order: str) -> Tensor:
    """Quaternions to Euler angles in radians listed in ``order`` (see :func:`matrix_to_euler`)."""
    return matrix_to_euler(quat_to_matrix(q), order)


def quat_slerp(a: Tensor, b: Tensor, t: Tensor | float) -> Tensor:
    """Spherical linear interpolation from ``a`` (t=0) to ``b`` (t=1) along the shorter arc.

    ``t`` broadcasts against the leading dimensions (shape ``(...)`` or ``(..., 1)``).
    """
    t = torch.as_tensor(t, dtype=a.dtype, device=a.device)
    if t.dim() < a.dim():
        t = t.unsqueeze(-1)
    dot = (a * b).sum(-1, keepdim=True)
    b = torch.where(dot < 0, -b, b)
    dot = dot.abs().clamp(max=1.0)
    theta = torch.acos(dot)
    sin_theta = torch.sin(theta)
    near = sin_theta < 1e-6
    safe = torch.where(near, torch.ones_like(sin_theta), sin_theta)
    wa = torch.where(near, 1.0 - t, torch.sin((1.0 - t) * theta) / safe)
    wb = torch.where(near, t, torch.sin(t * theta) / safe)
    return quat_normalize(wa * a + wb * b)


def yaw_quat(angle: Tensor) -> Tensor:
    """Rotations of ``angle (...)`` radians about the +Y (up) axis."""
    half = 0.5 * angle
    zero = torch.zeros_like(angle)
    return torch.stack([zero, torch.sin(half), zero, torch.cos(half)], dim=-1)


DEG = 180.0 / math.pi

"""Quaternion arithmetic in numpy for BVH files: x, y, z, w order, Hamilton product, float64.

BVH rotation channels are intrinsic Euler angles in degrees: a joint with channels ``Zrotation
Xrotation Yrotation`` has the local rotation ``Rz(a) @ Rx(b) @ Ry(c)``, which is the quaternion
product ``qz(a) * qx(b) * qy(c)``. :func:`euler_to_quat` and :func:`quat_to_euler` go between the
two for any axis order; :func:`quat_slerp` and :func:`make_continuous` serve resampling.
"""

from __future__ import annotations

import numpy as np

AXES = "XYZ"


def check_order(order: str) -> str:
    """``order`` in upper case, when it names X, Y and Z once each (``"ZXY"``); ValueError otherwise."""
    up = order.upper()
    if sorted(up) != list(AXES):
        raise ValueError(f"rotation order {order!r} must use X, Y and Z once each, e.g. 'ZXY'")
    return up


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product ``a * b`` (apply ``b``, then ``a``), broadcasting over leading axes."""
    av, aw = a[..., :3], a[..., 3:]
    bv, bw = b[..., :3], b[..., 3:]
    vec = aw * bv + bw * av + np.cross(av, bv)
    w = aw * bw - np.sum(av * bv, axis=-1, keepdims=True)
    return np.concatenate([vec, w], axis=-1)


def axis_quat(axis: str, radians: np.ndarray) -> np.ndarray:
    """Rotations by ``radians`` about one coordinate axis (``"X"``, ``"Y"`` or ``"Z"``): shape ``radians.shape + (4,)``."""
    half = np.asarray(radians, dtype=np.float64) / 2.0
    out = np.zeros(half.shape + (4,))
    out[..., AXES.index(axis.upper())] = np.sin(half)
    out[..., 3] = np.cos(half)
    return out


def euler_to_quat(degrees: np.ndarray, axes: str) -> np.ndarray:
    """Intrinsic rotations about ``axes`` in the order listed (any count, 0 to 3), angles ``[..., len(axes)]`` in degrees."""
    angles = np.radians(np.asarray(degrees, dtype=np.float64))
    out = np.zeros(angles.shape[:-1] + (4,))
    out[..., 3] = 1.0
    for n, axis in enumerate(axes):
        out = quat_mul(out, axis_quat(axis, angles[..., n]))
    return out


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions; ValueError when one is zero or not finite (no rotation can be read from it)."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~np.isfinite(norm) | (norm < 1e-12)
    if bad.any():
        where = np.argwhere(bad[..., 0])[0].tolist()
        raise ValueError(f"quaternion at index {where} is zero or not finite: {q[tuple(where)].tolist()}")
    return q / norm


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` of unit quaternions."""
    x, y, z, w = (q[..., i] for i in range(4))
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - z * w)
    m[..., 0, 2] = 2 * (x * z + y * w)
    m[..., 1, 0] = 2 * (x * y + z * w)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - x * w)
    m[..., 2, 0] = 2 * (x * z - y * w)
    m[..., 2, 1] = 2 * (y * z + x * w)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def quat_to_euler(q: np.ndarray, order: str) -> np.ndarray:
    """Intrinsic Euler angles in degrees, ``[..., 3]`` listed in ``order``, of (not necessarily unit) quaternions.

    For ``R = R_i(a) R_j(b) R_k(c)`` the middle angle ``b`` lies in [-90, 90]. ``c`` is solved from
    ``R_i(a)^T R = R_j(b) R_k(c)`` for the ``a`` found, so the three compose back to ``R`` to rounding
    even at gimbal lock (``b`` = +-90), where ``a`` and ``c`` are one degree of freedom.
    """
    i, j, k = (AXES.index(a) for a in check_order(order))
    s = 1.0 if (j - i) % 3 == 1 else -1.0  # +1 for the cyclic orders XYZ, YZX, ZXY
    m = quat_to_matrix(quat_normalize(q))
    a = np.arctan2(-s * m[..., j, k], m[..., k, k])
    b = np.arctan2(s * m[..., i, k], np.hypot(m[..., i, i], m[..., i, j]))
    ca, sa = np.cos(a), np.sin(a)
    # Row j of R_i(a)^T R is ca * R[j] + s * sa * R[k]; its entries i and j are s * sin(c) and cos(c).
    c = np.arctan2(s * (ca * m[..., j, i] + s * sa * m[..., k, i]), ca * m[..., j, j] + s * sa * m[..., k, j])
    return np.degrees(np.stack([a, b, c], axis=-1))


def make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 (time) so that consecutive quaternions lie in the same hemisphere."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[0] < 2:
        return q.copy()
    dots = np.sum(q[1:] * q[:-1], axis=-1, keepdims=True)
    signs = np.cumprod(np.where(dots < 0.0, -1.0, 1.0), axis=0)
    return np.concatenate([q[:1], q[1:] * signs], axis=0)


def quat_slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation from unit ``a`` (t = 0) to unit ``b`` (t = 1) along the shorter arc.

    ``t`` broadcasts against the leading axes of ``a`` with a trailing axis of 1.
    """
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    theta = np.arccos(np.clip(np.abs(dot), 0.0, 1.0))
    sin_theta = np.sin(theta)
    near = sin_theta < 1e-6  # nearly the same rotation: a straight line is as good and stays finite
    safe = np.where(near, 1.0, sin_theta)
    wa = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(near, t, np.sin(t * theta) / safe)
    return quat_normalize(wa * a + wb * b)

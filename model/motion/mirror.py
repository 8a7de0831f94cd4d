"""Left/right mirroring of motion, for any rig whose left/right pairs a profile names.

Mirroring reflects the world across the plane ``x = 0`` (matrix ``M = diag(-1, 1, 1)``) and swaps
each joint with its counterpart. Positions simply become ``M p[mirror]``. Rotations need one
more fact per joint: rigs orient the local axes of their left and right limbs differently (the
Bandai-Namco rig points both legs' x axes *along* the bone from opposite sides), so the mirrored
world rotation of joint ``j`` is ``M R[mirror[j]] A_j``, where ``A_j`` is an improper orthogonal
matrix, fixed per rig, that maps ``j``'s bone offsets onto those of its counterpart. ``A`` is
derived from the rest offsets alone (:func:`mirror_reflections`) with ``A[mirror[j]] = A_j^T``,
so mirroring twice is exactly the identity.
"""

from __future__ import annotations

import math

import torch

from model.motion.rotations import matrix_to_quat, quat_to_matrix
from model.motion.skeleton import Skeleton, SkeletonError

Tensor = torch.Tensor

WORLD_MIRROR = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))


def _improper_procrustes(u: Tensor, v: Tensor) -> Tensor:
    """The orthogonal matrix with determinant -1 that best maps rows of ``u`` onto rows of ``v``."""
    w, _, zt = torch.linalg.svd(v.T @ u)
    d = torch.ones(3, dtype=u.dtype)
    d[2] = -torch.det(w) * torch.det(zt)
    return w @ torch.diag(d) @ zt


def _axis_rotation(k: Tensor, angle: float) -> Tensor:
    """Rodrigues: the rotation by ``angle`` about the unit axis whose cross-product matrix is ``k``."""
    eye = torch.eye(3, dtype=k.dtype)
    return eye + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _family(u: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
    """Improper orthogonal matrices taking direction ``u`` to ``v`` form ``h @ Rot(u, phi)``:
    returns ``h`` and the cross-product matrix ``k`` of the unit ``u``."""
    u = u / u.norm()
    v = v / v.norm()
    n = u - v
    if n.norm() < 1e-6:  # u == v: start from any plane containing u
        other = torch.tensor([1.0, 0.0, 0.0], dtype=u.dtype)
        if u[0].abs() > 0.9:
            other = torch.tensor([0.0, 1.0, 0.0], dtype=u.dtype)
        n = torch.linalg.cross(u, other)
    n = n / n.norm()
    h = torch.eye(3, dtype=u.dtype) - 2.0 * torch.outer(n, n)  # a reflection with h @ u == v
    k = torch.tensor([[0.0, -u[2], u[1]], [u[2], 0.0, -u[0]], [-u[1], u[0], 0.0]], dtype=u.dtype)
    return h, k


def _best_in_family(h: Tensor, k: Tensor, b_mat: Tensor) -> Tensor | None:
    """The member ``A = h Rot(phi)`` maximising ``tr(Rot(phi) b_mat)`` (closed form via Rodrigues),
    or None when every member scores the same."""
    b = torch.trace(k @ b_mat)
    c = torch.trace(k @ k @ b_mat)
    if torch.hypot(b, c) < 1e-6:
        return None
    phi = float(torch.atan2(b, -c))
    return h @ _axis_rotation(k, phi)


def _single_axis_reflection(u: Tensor, v: Tensor, prefer: Tensor, fit: Tensor | None) -> Tensor:
    """An improper orthogonal matrix taking direction ``u`` to ``v``.

    One bone leaves a one-parameter family ``A = h Rot(u, phi)`` (a twist about the bone), chosen
    by the first criterion that tells members apart:

    1. with reference motion, ``fit = R_j^T C`` where the mirrored mean local rotation is ``C @ A``
       and ``R_j`` is the joint's own mean: the member making the two closest. Rigs whose rest
       pose is not anatomical (Bandai-Namco's spine turns its lateral axis from y to z between
       hips and chest) can only be read from motion;
    2. the member closest to the parent's reflection ``prefer`` (a convention kept down a chain);
    3. the member closest to ``-I``, the convention of rigs with mirrored limb axes ("behaviour"
       mirroring, as in the Bandai-Namco limbs).
    """
    h, k = _family(u, v)
    # Each criterion maximises tr(Rot(phi) B): for tr(X^T A) it is B = X^T h, for fit B = fit h.
    targets = ([fit @ h] if fit is not None else []) + [prefer.T @ h, -h]
    for b_mat in targets:
        best = _best_in_family(h, k, b_mat)
        if best is not None:
            return best
    return h


def _mean_rotation(q: Tensor) -> Tensor:
    """The rotation matrix nearest the chordal mean of rotations ``[N, 4]`` (float64)."""
    u, _, vt = torch.linalg.svd(quat_to_matrix(q.double()).mean(0))
    d = torch.ones(3, dtype=torch.float64)
    d[2] = torch.det(u @ vt)
    return u @ torch.diag(d) @ vt


def mirror_reflections(skeleton: Skeleton, reference: Tensor | None = None) -> Tensor:
    """Per-joint improper matrices ``A [J, 3, 3]`` (float64) used by :func:`mirror_global`.

    Args:
        skeleton: the rig.
        reference: optional local rotations ``[N, J, 4]`` of typical motion (a few takes with as
            much left as right in them), used to settle the twist of single-bone joints.
    """
    means = None
    if reference is not None:
        ref = reference.reshape(-1, skeleton.num_joints, 4)
        means = [_mean_rotation(ref[:, j]) for j in range(skeleton.num_joints)]
    offsets = skeleton.offsets_tensor(torch.float64)
    mirror = skeleton.mirror
    parents = skeleton.parents
    out: list[Tensor | None] = [None] * skeleton.num_joints
    for j in range(skeleton.num_joints):
        if out[j] is not None:
            continue
        mj = mirror[j]
        kids = [c for c in skeleton.children[j] if offsets[c].norm() > 1e-6]
        mkids = [mirror[c] for c in kids]
        if any(parents[mc] != mj for mc in mkids):
            raise SkeletonError(
                f"mirror pairs are inconsistent at joint {skeleton.names[j]!r}: its children's "
                f"counterparts are not children of {skeleton.names[mj]!r}"
            )
        parent_a = out[parents[j]] if parents[j] >= 0 else None
        prefer = parent_a if parent_a is not None else WORLD_MIRROR
        if kids:
            u, v = offsets[kids], offsets[mkids]
            if len(kids) >= 2 and torch.linalg.matrix_rank(u, atol=1e-3) >= 2:
                a = _improper_procrustes(u, v)
            else:
                fit = None
                if means is not None and parent_a is not None:
                    fit = means[j].T @ parent_a.T @ means[mj]
                a = _single_axis_reflection(u.sum(0), v.sum(0), prefer, fit)
        else:
            a = prefer.clone()
        if mj == j:
            # A midline joint's reflection must be an involution; symmetrise against round-off.
            a = 0.5 * (a + a.T)
        out[j] = a
        out[mj] = a.T
    return torch.stack([a for a in out if a is not None])


def mirror_global(
    positions: Tensor, rotations: Tensor, skeleton: Skeleton, reflections: Tensor | None = None
) -> tuple[Tensor, Tensor]:
    """Mirror world positions ``[..., J, 3]`` and world rotations ``[..., J, 4]`` across x = 0."""
    a = mirror_reflections(skeleton) if reflections is None else reflections
    idx = torch.tensor(skeleton.mirror)
    m = WORLD_MIRROR.to(positions.dtype)
    pos = positions.index_select(-2, idx) @ m.T
    mats = quat_to_matrix(rotations.index_select(-2, idx).double())
    mats = WORLD_MIRROR @ mats @ a
    return pos, matrix_to_quat(mats).to(rotations.dtype)

"""Per-frame motion features as the paper uses them, the canonical frame, and the way back.

Conventions: Y is up; a character's *facing* is the horizontal direction ``up x (right - left)``
of its hips and shoulders; the canonical frame turns the facing of a chosen frame to **+Z** and
moves that frame's root to the origin on the ground (y is kept). Velocities are per-frame
displacements in cm/frame at the clip's fps (30 for the model).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from model.motion.clip import Clip
from model.motion.kinematics import global_to_local_rotations
from model.motion.rotations import quat_mul, quat_rotate, quat_to_sixd, sixd_to_quat, yaw_quat
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

# Soft contact thresholds on foot speed (cm/frame at 30 fps), from the RSMT reference (1.8).
CONTACT_SLOW = 0.5
CONTACT_FAST = 1.0


def facing_directions(global_positions: Tensor, skeleton: Skeleton) -> Tensor:
    """Unit horizontal facing vectors ``[..., 3]`` from positions ``[..., J, 3]``."""
    r = skeleton.roles
    across = (global_positions[..., r.right_hip, :] - global_positions[..., r.left_hip, :]) + (
        global_positions[..., r.right_shoulder, :] - global_positions[..., r.left_shoulder, :]
    )
    # up x across, with up = +Y: (x, y, z) -> (z, 0, -x)
    fwd = torch.stack([across[..., 2], torch.zeros_like(across[..., 0]), -across[..., 0]], dim=-1)
    return fwd / fwd.norm(dim=-1, keepdim=True).clamp_min(1e-8)


def facing_yaw(global_positions: Tensor, skeleton: Skeleton) -> Tensor:
    """Facing angle ``[...]`` in radians about +Y; 0 faces +Z, pi/2 faces +X."""
    f = facing_directions(global_positions, skeleton)
    return torch.atan2(f[..., 0], f[..., 2])


@dataclass(frozen=True)
class FacingChains:
    """What the facing of a pose needs when only its global rotations are known (a generated frame's
    rotations are what leaves the engine).

    The facing is ``up x across``, with ``across = (right hip - left hip) + (right shoulder - left
    shoulder)``. Each facing joint sits at the root plus its chain's offsets, each turned by its
    parent's global rotation, so ``across`` is a sum over joints ``k`` of ``R_k w_k``: ``w_k`` adds the
    offsets of ``k``'s children on the right chains and takes away those on the left ones. The chain
    shared by both shoulders cancels; only the few joints with ``w_k != 0`` are kept.

    Attributes:
        joints: ``[K]`` the joints whose rotation moves ``across``.
        weights: ``[K, 3]`` their ``w_k`` (cm, in the joint's own frame).
    """

    joints: Tensor
    weights: Tensor

    @classmethod
    def of(cls, skeleton: Skeleton) -> FacingChains:
        r = skeleton.roles
        offsets = skeleton.offsets_tensor()
        w = torch.zeros(skeleton.num_joints, 3)
        for sign, joint in ((-1.0, r.left_hip), (1.0, r.right_hip), (-1.0, r.left_shoulder), (1.0, r.right_shoulder)):
            while joint != r.root and joint >= 0:
                w[skeleton.parents[joint]] += sign * offsets[joint]
                joint = skeleton.parents[joint]
        keep = (w.abs() > 1e-9).any(-1).nonzero().flatten()
        return cls(keep, w[keep].clone())

    def yaw(self, rotations_6d: Tensor) -> Tensor:
        """Facing angle ``[...]`` (radians, as :func:`facing_yaw`) of global rotations ``[..., J, 6]``
        whose two columns are orthonormal (as the sampler keeps them)."""
        a = rotations_6d[..., self.joints, :]
        c1, c2 = a[..., :3], a[..., 3:]
        c3 = torch.linalg.cross(c1, c2)
        w = self.weights
        across = (c1 * w[:, :1] + c2 * w[:, 1:2] + c3 * w[:, 2:]).sum(-2)
        return torch.atan2(across[..., 2], -across[..., 0])


def _expand(t: Tensor, target_dim: int) -> Tensor:
    """Append singleton dims so a per-clip tensor ``[B, k]`` broadcasts over ``[B, ..., k]``."""
    while t.dim() < target_dim:
        t = t.unsqueeze(-2)
    return t


@dataclass(frozen=True)
class CanonicalFrame:
    """A yaw and ground origin per clip: ``p_canonical = R_y(-yaw) (p - origin)``.

    Attributes:
        yaw: ``[...]`` facing angle of the reference frame (radians, 0 = +Z).
        origin: ``[..., 3]`` the reference frame's root projected on the ground (y = 0).
    """

    yaw: Tensor
    origin: Tensor

    @classmethod
    def at_frame(cls, global_positions: Tensor, skeleton: Skeleton, frame: int) -> CanonicalFrame:
        """The canonical frame of frame ``frame`` of positions ``[..., T, J, 3]``."""
        ref = global_positions[..., frame, :, :]
        origin = ref[..., skeleton.roles.root, :].clone()
        origin[..., 1] = 0.0
        return cls(yaw=facing_yaw(ref, skeleton), origin=origin)

    def _quat(self, inverse: bool) -> Tensor:
        return yaw_quat(-self.yaw if inverse else self.yaw)

    def positions_to(self, p: Tensor) -> Tensor:
        """World positions ``[..., *, 3]`` into the canonical frame."""
        q = _expand(self._quat(True), p.dim())
        return quat_rotate(q, p - _expand(self.origin, p.dim()))

    def positions_from(self, p: Tensor) -> Tensor:
        q = _expand(self._quat(False), p.dim())
        return quat_rotate(q, p) + _expand(self.origin, p.dim())

    def vectors_from(self, v: Tensor) -> Tensor:
        """Canonical vectors ``[..., *, 3]`` (velocities, displacements) in the world: turned, not moved."""
        return quat_rotate(_expand(self._quat(False), v.dim()), v)

    def rotations_to(self, r: Tensor) -> Tensor:
        """World rotations ``[..., *, 4]`` into the canonical frame."""
        return quat_mul(_expand(self._quat(True), r.dim()), r)

    def rotations_from(self, r: Tensor) -> Tensor:
        return quat_mul(_expand(self._quat(False), r.dim()), r)


@dataclass(frozen=True)
class MotionFeatures:
    """Per-frame features in one frame of reference.

    Attributes:
        positions: ``[..., T, J, 3]`` global joint positions (cm).
        velocities: ``[..., T, J, 3]`` ``p[t] - p[t-1]`` (cm/frame); frame 0 repeats frame 1.
        rotations_6d: ``[..., T, J, 6]`` global joint rotations in 6D.
        contacts: ``[..., T, F]`` soft foot contacts in [0, 1] for ``skeleton.feet``.
    """

    positions: Tensor
    velocities: Tensor
    rotations_6d: Tensor
    contacts: Tensor


def velocities(positions: Tensor) -> Tensor:
    """Backward differences along time (dim -3), frame 0 repeating frame 1."""
    if positions.shape[-3] < 2:
        return torch.zeros_like(positions)
    v = positions[..., 1:, :, :] - positions[..., :-1, :, :]
    return torch.cat([v[..., :1, :, :], v], dim=-3)


def soft_contacts(foot_velocities: Tensor, slow: float = CONTACT_SLOW, fast: float = CONTACT_FAST) -> Tensor:
    """Soft contact per foot sample from its speed: 1 below ``slow``, 0 above ``fast``, smooth between.

    Args:
        foot_velocities: ``[..., F, 3]`` displacements in cm/frame.
    """
    speed = foot_velocities.norm(dim=-1)
    x = ((speed - slow) / (fast - slow)).clamp(0.0, 1.0)
    return 1.0 - x * x * (3.0 - 2.0 * x)


def compute_features(global_positions: Tensor, global_rotations: Tensor, skeleton: Skeleton) -> MotionFeatures:
    """Features of motion given as positions ``[..., T, J, 3]`` and rotations ``[..., T, J, 4]``."""
    vel = velocities(global_positions)
    feet = torch.tensor(skeleton.feet)
    return MotionFeatures(
        positions=global_positions,
        velocities=vel,
        rotations_6d=quat_to_sixd(global_rotations),
        contacts=soft_contacts(vel.index_select(-2, feet)),
    )


def features_to_local(
    positions: Tensor, rotations_6d: Tensor, skeleton: Skeleton, frame: CanonicalFrame | None = None
) -> tuple[Tensor, Tensor]:
    """Back from features to ``(local_rotations [..., T, J, 4], root_positions [..., T, 3])``.

    With ``frame`` the result is returned to the world frame the features were taken from.
    """
    rot = sixd_to_quat(rotations_6d)
    root = positions[..., skeleton.roles.root, :]
    if frame is not None:
        rot = frame.rotations_from(rot)
        root = frame.positions_from(root)
    return global_to_local_rotations(rot, skeleton.parents), root


def temporal_rescale(clip: Clip, generator: torch.Generator | None = None) -> Clip:
    """RSMT's temporal-rescale augmentation: a random crop replayed faster or slower.

    Crop a random span of ``d`` frames with ``T/2 <= d <= T``; short crops are slowed down
    (speed factor ``g`` in ``[1, 2]`` more frames), long ones sped up (``g`` in ``[0.5, 1]``); the
    result is resampled to ``int(d * g)`` frames and cut to at most ``T`` frames.
    """
    t = clip.num_frames
    if t < 4:
        return clip
    u = torch.rand(3, generator=generator, dtype=torch.float64).tolist()
    span = int(t // 2 + u[0] * (t - t // 2))
    span = max(2, min(span, t))
    start = int(u[1] * (t - span + 1))
    start = min(start, t - span)
    gamma = 1.0 + u[2] if span < 0.75 * t else 0.5 + 0.5 * u[2]
    crop = clip.window(start, start + span)
    out = crop.retime(1.0 / gamma)
    if out.num_frames > t:
        out = out.window(0, t)
    return replace(out, name=f"rescale({clip.name})" if clip.name else "rescale")



def local_frame_features(global_positions: Tensor, global_rotations: Tensor, skeleton: Skeleton) -> Tensor:
    """Each frame in its own canonical frame (its facing to +Z, its root over the origin).

    The style encoder's input, as in RSMT: invariant to where and which way the clip moves, so a
    style code carries posture and rhythm, not a path. Returns ``[..., T-1, J*12]``: per joint the
    position, the velocity ``p[t] - p[t-1]`` (both turned by frame ``t``'s facing) and the 6D
    rotation, for frames ``1..T-1`` (frame 0 has no velocity).
    """
    yaw = facing_yaw(global_positions, skeleton)[..., 1:]  # [..., T-1]
    root = global_positions[..., 1:, skeleton.roles.root, :].clone()
    root[..., 1] = 0.0
    turn = yaw_quat(-yaw).unsqueeze(-2)  # [..., T-1, 1, 4]
    pos = quat_rotate(turn, global_positions[..., 1:, :, :] - root.unsqueeze(-2))
    vel = quat_rotate(turn, global_positions[..., 1:, :, :] - global_positions[..., :-1, :, :])
    rot = quat_to_sixd(quat_mul(turn, global_rotations[..., 1:, :, :]))
    return torch.cat([pos, vel, rot], dim=-1).flatten(-2)

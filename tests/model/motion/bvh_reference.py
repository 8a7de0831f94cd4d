"""An independent reference for the BVH tests: world transforms straight from BVH's semantics
(4x4 matrices in NumPy, no code shared with ``model.motion``), and angle comparisons."""

from __future__ import annotations

import math

import numpy as np

from model.motion.bvh import BvhDocument


def axis_matrix(axis: str, degrees: np.ndarray) -> np.ndarray:
    a = np.deg2rad(degrees)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    i = "XYZ".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    m[..., i, i] = 1.0
    m[..., j, j] = c
    m[..., k, k] = c
    m[..., k, j] = s
    m[..., j, k] = -s
    return m


def euler_matrix(degrees: np.ndarray, order: str) -> np.ndarray:
    """``R = R_order[0](a0) @ R_order[1](a1) @ ...``, for any number of listed axes."""
    m = np.broadcast_to(np.eye(3), degrees.shape[:-1] + (3, 3)).copy()
    for n, axis in enumerate(order):
        m = m @ axis_matrix(axis, degrees[..., n])
    return m


def channel_column(doc: BvhDocument, joint: str, channel: str) -> int:
    """The motion column of one joint's channel (``Xposition``, ``Zrotation``, ...), counted from the joints."""
    i = [j.name for j in doc.joints].index(joint)
    return sum(len(j.channels) for j in doc.joints[:i]) + list(doc.joints[i].channels).index(channel)


def reference_world(doc: BvhDocument) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World ``(positions [T, 3], rotations [T, 3, 3])`` per joint name, straight from BVH semantics.

    Each joint's local transform is ``Translate(t) @ Rotate``, with ``t`` the OFFSET whose
    components are replaced by the joint's position channels, and ``Rotate`` the product of its
    rotation channels in the order listed. 4x4 matrices, composed parent first.
    """
    frames = doc.num_frames
    world: list[np.ndarray] = []
    col = 0
    out = {}
    for joint in doc.joints:
        values = doc.motion[:, col:col + len(joint.channels)]
        col += len(joint.channels)
        t = np.tile(np.array(joint.offset), (frames, 1))
        rot_cols, rot_axes = [], ""
        for k, ch in enumerate(joint.channels):
            if ch.endswith("position"):
                t[:, "XYZ".index(ch[0])] = values[:, k]
            else:
                rot_cols.append(k)
                rot_axes += ch[0]
        local = np.tile(np.eye(4), (frames, 1, 1))
        local[:, :3, :3] = euler_matrix(values[:, rot_cols], rot_axes)
        local[:, :3, 3] = t
        m = local if joint.parent < 0 else world[joint.parent] @ local
        world.append(m)
        out[joint.name] = (m[:, :3, 3], m[:, :3, :3])
    return out


def angle_between_matrices(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle of ``a^T b`` in degrees, accurate for tiny angles (chord formula)."""
    chord = np.linalg.norm(a - b, axis=(-2, -1)) / (2.0 * math.sqrt(2.0))
    return np.rad2deg(2.0 * np.arcsin(np.clip(chord, 0.0, 1.0)))


def wrapped_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)

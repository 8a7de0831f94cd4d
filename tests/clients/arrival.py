"""How far a generated clip ends from a ``target_at`` place and facing, measured as the model measures a facing;
shared by the Python, Unity and Unreal client tests of ``target_at``."""

from __future__ import annotations

import math

import numpy as np
import torch
from rsmt_client import TargetAt

from model.motion.features import facing_yaw
from model.motion.kinematics import forward_kinematics
from model.motion.skeleton import Skeleton


def facing_deg(skeleton: Skeleton, roots: np.ndarray, rotations: np.ndarray) -> float:
    """The facing of the last of these poses, as the model defines it (up x (right - left) of hips and shoulders)."""
    positions, _ = forward_kinematics(torch.from_numpy(np.asarray(rotations, np.float64))[-1],
                                      torch.from_numpy(np.asarray(roots, np.float64))[-1],
                                      skeleton.offsets_tensor(torch.float64), skeleton.parents)
    return math.degrees(float(facing_yaw(positions, skeleton)))


def place_from(skeleton: Skeleton, roots: np.ndarray, rotations: np.ndarray, ahead: float, side: float,
               turn: float) -> TargetAt:
    """A place ``ahead`` along the last pose's facing and ``side`` to its left (model units) from its root, facing
    ``turn`` degrees more than it does now."""
    here = np.asarray(roots, np.float64)[-1]
    yaw = facing_deg(skeleton, roots, rotations)
    f = np.array([math.sin(math.radians(yaw)), math.cos(math.radians(yaw))])  # (x, z) ahead
    left = np.array([f[1], -f[0]])  # ahead turned +90 degrees about +Y
    xz = here[[0, 2]] + ahead * f + side * left
    return TargetAt(float(xz[0]), float(xz[1]), yaw + turn)


def miss(skeleton: Skeleton, place: TargetAt, roots: np.ndarray, rotations: np.ndarray) -> tuple[float, float]:
    """How far the last frame's root lies from the place (model units) and its facing from the one asked (degrees)."""
    roots = np.asarray(roots, np.float64)
    distance = math.hypot(float(roots[-1, 0]) - place.x, float(roots[-1, 2]) - place.z)
    turn = (facing_deg(skeleton, roots[-1:], np.asarray(rotations)[-1:]) - place.yaw + 180.0) % 360.0 - 180.0
    return distance, abs(turn)

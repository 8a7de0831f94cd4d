"""Procedural motion on a small synthetic rig, so tests and smoke runs need no motion data.

The rig uses the Bandai-Namco joint names (so the built-in profile resolves it) with round-number
offsets of our own, upright at rest, Y up, facing +Z (its left is +X). The walk is a sinusoidal
gait along a path that may turn; it is plausible in shape, not physically exact.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from model.motion.clip import Clip
from model.motion.rotations import axis_angle_to_quat, quat_mul, yaw_quat
from model.motion.skeleton import Skeleton

# name, parent name, offset (cm)
_RIG = [
    ("Hips", None, (0.0, 0.0, 0.0)),
    ("Spine", "Hips", (0.0, 10.0, 0.0)),
    ("Chest", "Spine", (0.0, 15.0, 0.0)),
    ("Neck", "Chest", (0.0, 20.0, 0.0)),
    ("Head", "Neck", (0.0, 10.0, 0.0)),
    ("Shoulder_L", "Chest", (4.0, 18.0, 0.0)),
    ("UpperArm_L", "Shoulder_L", (12.0, 0.0, 0.0)),
    ("LowerArm_L", "UpperArm_L", (26.0, 0.0, 0.0)),
    ("Hand_L", "LowerArm_L", (24.0, 0.0, 0.0)),
    ("Shoulder_R", "Chest", (-4.0, 18.0, 0.0)),
    ("UpperArm_R", "Shoulder_R", (-12.0, 0.0, 0.0)),
    ("LowerArm_R", "UpperArm_R", (-26.0, 0.0, 0.0)),
    ("Hand_R", "LowerArm_R", (-24.0, 0.0, 0.0)),
    ("UpperLeg_L", "Hips", (9.0, -5.0, 0.0)),
    ("LowerLeg_L", "UpperLeg_L", (0.0, -42.0, 0.0)),
    ("Foot_L", "LowerLeg_L", (0.0, -41.0, 0.0)),
    ("Toes_L", "Foot_L", (0.0, -7.0, 13.0)),
    ("UpperLeg_R", "Hips", (-9.0, -5.0, 0.0)),
    ("LowerLeg_R", "UpperLeg_R", (0.0, -42.0, 0.0)),
    ("Foot_R", "LowerLeg_R", (0.0, -41.0, 0.0)),
    ("Toes_R", "Foot_R", (0.0, -7.0, 13.0)),
]
HIP_HEIGHT_CM = 92.0


def synthetic_skeleton() -> Skeleton:
    """The synthetic rig (21 joints, Bandai-Namco names, cm)."""
    names = [n for n, _, _ in _RIG]
    parents = [-1 if p is None else names.index(p) for _, p, _ in _RIG]
    end_sites = tuple((names.index(n), (0.0, 0.0, 0.0)) for n in ("Head", "Hand_L", "Hand_R", "Toes_L", "Toes_R"))
    return Skeleton.build(names, parents, [o for _, _, o in _RIG], profile="bandai-namco", end_sites=end_sites)


def synthetic_walk(
    frames: int = 90,
    fps: float = 30.0,
    speed_cm_s: float = 120.0,
    turn_deg_s: float = 0.0,
    cadence_hz: float = 0.9,
    start_yaw_deg: float = 0.0,
    stride_deg: float = 25.0,
    phase: float = 0.0,
) -> Clip:
    """A walk of ``frames`` frames: forward along the facing, turning ``turn_deg_s`` (left > 0)."""
    sk = synthetic_skeleton()
    t = torch.arange(frames, dtype=torch.float64) / fps
    yaw = math.radians(start_yaw_deg) + math.radians(turn_deg_s) * t
    # Integrate the path: velocity along the facing (sin yaw, 0, cos yaw).
    step = speed_cm_s / fps
    dx = step * torch.sin(yaw)
    dz = step * torch.cos(yaw)
    x = torch.cumsum(dx, 0) - dx[0]
    z = torch.cumsum(dz, 0) - dz[0]
    w = 2 * math.pi * cadence_hz * t + phase
    y = HIP_HEIGHT_CM + 1.5 * torch.cos(2 * w)
    root = torch.stack([x, y, z], dim=-1)

    j = sk.num_joints
    rot = torch.zeros(frames, j, 4, dtype=torch.float64)
    rot[..., 3] = 1.0
    ex = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).expand(frames, 3)
    ez = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(frames, 3)
    swing = math.radians(stride_deg) * torch.sin(w)
    knee = math.radians(stride_deg) * (1.0 + torch.sin(w + math.pi / 2)).clamp_min(0)
    rot[:, 0] = yaw_quat(yaw)
    for side, sign in (("L", 1.0), ("R", -1.0)):
        s = swing * sign
        rot[:, sk.index(f"UpperLeg_{side}")] = axis_angle_to_quat(ex, -s)
        rot[:, sk.index(f"LowerLeg_{side}")] = axis_angle_to_quat(ex, knee if sign > 0 else knee.roll(frames // 2))
        rot[:, sk.index(f"UpperArm_{side}")] = quat_mul(
            axis_angle_to_quat(ez, -sign * torch.full_like(t, math.radians(70.0))), axis_angle_to_quat(ex, 0.6 * s)
        )
    rot[:, sk.index("Spine")] = axis_angle_to_quat(ex, torch.full_like(t, math.radians(4.0)))
    return Clip(skeleton=sk, rotations=rot.float(), root_positions=root.float(), fps=fps, name="synthetic-walk")


# Per synthetic "style": speed (cm/s), cadence (Hz) and stride (degrees), so styles differ in rhythm.
SYNTHETIC_STYLES = {
    "brisk": (150.0, 1.1, 30.0),
    "slow": (70.0, 0.7, 18.0),
    "bouncy": (110.0, 1.4, 35.0),
}
SYNTHETIC_CONTENTS = {"walk": 0.0, "walk-turn-left": 40.0, "walk-turn-right": -40.0}


def write_synthetic_dataset(folder: str | Path, takes_per_pair: int = 3, frames: int = 150, fps: float = 30.0) -> list:
    """Write BVH takes named like Bandai-Namco's (``dataset-2_{content}_{style}_{NNN}.bvh``).

    3 styles x 3 contents x ``takes_per_pair`` takes of procedural walking; returns the paths.
    """
    from model.motion.bvh_clip import dump_clip

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for s_i, (style, (speed, cadence, stride)) in enumerate(SYNTHETIC_STYLES.items()):
        for content, turn in SYNTHETIC_CONTENTS.items():
            for n in range(takes_per_pair):
                clip = synthetic_walk(frames=frames, fps=fps, speed_cm_s=speed * (1 + 0.05 * n), turn_deg_s=turn,
                                      cadence_hz=cadence, stride_deg=stride, start_yaw_deg=37.0 * (n + s_i),
                                      phase=0.7 * n)
                path = folder / f"dataset-2_{content}_{style}_{n + 1:03d}.bvh"
                path.write_text(dump_clip(clip))
                paths.append(path)
    return paths

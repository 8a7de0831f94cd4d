"""Far starts and mid-stream retargets (issue 50 item 4): the cases of the reach sweep and the gait figures read
from what came back.

A case is a captured walk's last context frames (the data's test split, one style each), and a target pose
2-8 m away in 1-3 s: the context's last pose carried over the ground, at an angle of at most 60 degrees off its
facing, and turned to face along the way. A start goes there at once; a retarget first walks to the take's own
pose 40 frames on, and is sent the far target after 10-20 frames, measured from where the root then stands.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np
import torch

from model.data.preprocessed import MotionCache
from model.motion import gait
from model.motion.clip import Clip
from model.motion.features import facing_yaw
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_mul, quat_normalize, yaw_quat
from model.motion.skeleton import Skeleton

CONTEXT = 10
NATURAL_FRAMES = 40


@dataclass(frozen=True)
class SweepCase:
    """One start (``retarget_at`` None: ``context`` straight to the far target) or one retarget (first to
    ``natural``, the far target sent at frame ``retarget_at``). ``distance_cm``, ``angle_deg`` (off the facing)
    and ``frames`` say where the far target lies and when it is due."""

    style: str
    context: Clip
    natural: Clip
    distance_cm: float
    angle_deg: float
    frames: int
    retarget_at: int | None


def far_target(pose: Clip, root_xz: np.ndarray, facing_deg: float, distance_cm: float, angle_deg: float) -> Clip:
    """``pose`` (its last frame) moved to ``distance_cm`` from ``root_xz`` at ``angle_deg`` off ``facing_deg``
    (degrees about +Y, 0 facing +Z) and turned by that angle, so it faces along the way."""
    rot = pose.rotations[-1:].clone()
    root = pose.root_positions[-1:].clone()
    heading = math.radians(facing_deg + angle_deg)
    root[0, 0] = float(root_xz[0]) + distance_cm * math.sin(heading)
    root[0, 2] = float(root_xz[1]) + distance_cm * math.cos(heading)
    rot[0, 0] = quat_normalize(quat_mul(yaw_quat(torch.tensor(math.radians(angle_deg))), rot[0, 0]))
    return Clip(pose.skeleton, rot, root, pose.fps, f"{pose.name}-far")


def facing_deg(skeleton: Skeleton, root: np.ndarray, rotations: np.ndarray) -> float:
    """The facing (degrees about +Y, 0: +Z) of the pose ``root [3]``, local ``rotations [J, 4]``."""
    pos = positions(skeleton, np.asarray(root, np.float64)[None], np.asarray(rotations, np.float64)[None])
    return math.degrees(float(facing_yaw(torch.as_tensor(pos), skeleton)[0]))


def sweep_cases(cache: MotionCache, count: int, seed: int = 0) -> list[SweepCase]:
    """``count`` cases (half starts, half retargets), every style of the cache's test split in turn."""
    rng = random.Random(seed)
    test = sorted(cache.split.test, key=lambda i: cache.takes[i].take_id)
    walks = {s: [i for i in test if cache.takes[i].style == s and cache.takes[i].content == "walk"
                 and cache.num_frames(i) >= CONTEXT + NATURAL_FRAMES + 40] for s in cache.styles}
    styles = [s for s in cache.styles if walks[s]]
    cases = []
    for n in range(count):
        style = styles[n % len(styles)]
        take = cache.clip(rng.choice(walks[style]))
        start = rng.randrange(20, take.num_frames - CONTEXT - NATURAL_FRAMES)
        context = take.window(start, start + CONTEXT)
        natural = take.window(start + CONTEXT + NATURAL_FRAMES - 1, start + CONTEXT + NATURAL_FRAMES)
        cases.append(SweepCase(style, context, natural, rng.uniform(200.0, 800.0), rng.uniform(-60.0, 60.0),
                               rng.randrange(30, 91), None if n % 2 == 0 else rng.randrange(10, 21)))
    return cases


def positions(skeleton: Skeleton, roots: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """World joint positions ``[T, J, 3]`` of roots ``[T, 3]`` and local rotations ``[T, J, 4]``."""
    pos, _ = forward_kinematics(torch.as_tensor(rotations, dtype=torch.float64),
                                torch.as_tensor(roots, dtype=torch.float64), skeleton.offsets_tensor(torch.float64),
                                skeleton.parents)
    return pos.numpy()


@dataclass(frozen=True)
class GaitFigures:
    """Of one run's frames (the context's last pose first): frames with both toes more than 15 cm above rest,
    the longest run of them, the frames counted, the root's horizontal speeds (cm/s) frame to frame, and the
    hips' lowest and highest height over the generated frames."""

    airborne: int
    longest_airborne: int
    frames: int
    speeds: np.ndarray
    hips_cm: tuple[float, float]


def gait_figures(skeleton: Skeleton, pos: np.ndarray, fps: float) -> GaitFigures:
    """:class:`GaitFigures` of positions ``[T, J, 3]`` (toes' rest height: the rig's, :data:`gait.TOE_REST_CM`)."""
    toes = list(gait.toe_joints(skeleton))
    up: np.ndarray = np.asarray((pos[:, toes, 1] - gait.TOE_REST_CM > gait.AIRBORNE_CM).all(-1))
    longest = run = 0
    for flag in up.tolist():
        run = run + 1 if flag else 0
        longest = max(longest, run)
    root = pos[:, skeleton.roles.root]
    speeds = np.linalg.norm(np.diff(root[:, [0, 2]], axis=0), axis=-1) * fps
    hips = root[1:, 1]
    return GaitFigures(int(up[1:].sum()), longest, len(pos) - 1, speeds, (float(hips.min()), float(hips.max())))

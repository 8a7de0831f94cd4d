"""A converter for the tests: real Bandai-Namco takes rewritten on a CMU/MotionBuilder-style rig.

The converted rig has the CMU joint names and layout (31 joints): hip helpers ``LHipJoint`` and
``RHipJoint`` with zero offsets sitting on the hips, ``LowerBack`` and ``Neck1`` helpers, and under
each hand a ``LeftFingerBase``/``LeftHandIndex1`` finger and a ``LThumb``. The Bandai-Namco joints
keep their motion (helpers do not rotate), so the poses are the capture's; lengths are written in
metres or inches, at 120 fps, with CMU's Z-Y-X rotation channels. A manifest labels the files,
whose names carry no labels.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import torch

from model.motion.bvh_clip import dump_clip, load_clip
from model.motion.clip import Clip
from model.motion.rig_facts import CM_PER_UNIT
from model.motion.skeleton import Skeleton, SkeletonProfile

# CMU joint, its parent, and the Bandai-Namco joint whose motion and offset it takes (None: a helper
# with a zero offset and no rotation, or a finger with the given offset in cm along the hand).
CMU_JOINTS: tuple[tuple[str, str | None, str | None], ...] = (
    ("Hips", None, "Hips"),
    ("LHipJoint", "Hips", None), ("LeftUpLeg", "LHipJoint", "UpperLeg_L"), ("LeftLeg", "LeftUpLeg", "LowerLeg_L"),
    ("LeftFoot", "LeftLeg", "Foot_L"), ("LeftToeBase", "LeftFoot", "Toes_L"),
    ("RHipJoint", "Hips", None), ("RightUpLeg", "RHipJoint", "UpperLeg_R"), ("RightLeg", "RightUpLeg", "LowerLeg_R"),
    ("RightFoot", "RightLeg", "Foot_R"), ("RightToeBase", "RightFoot", "Toes_R"),
    ("LowerBack", "Hips", None), ("Spine", "LowerBack", "Spine"), ("Spine1", "Spine", "Chest"),
    ("Neck", "Spine1", "Neck"), ("Neck1", "Neck", None), ("Head", "Neck1", "Head"),
    ("LeftShoulder", "Spine1", "Shoulder_L"), ("LeftArm", "LeftShoulder", "UpperArm_L"),
    ("LeftForeArm", "LeftArm", "LowerArm_L"), ("LeftHand", "LeftForeArm", "Hand_L"),
    ("LeftFingerBase", "LeftHand", None), ("LeftHandIndex1", "LeftFingerBase", "finger"), ("LThumb", "LeftHand", None),
    ("RightShoulder", "Spine1", "Shoulder_R"), ("RightArm", "RightShoulder", "UpperArm_R"),
    ("RightForeArm", "RightArm", "LowerArm_R"), ("RightHand", "RightForeArm", "Hand_R"),
    ("RightFingerBase", "RightHand", None), ("RightHandIndex1", "RightFingerBase", "finger"), ("RThumb", "RightHand", None),
)
FINGER_CM = 7.0
# The profile the converted rig is built with (and that rsmt profile guess must find).
CMU_PROFILE = {
    "name": "cmu-test", "root": "Hips", "head": "Head", "left_foot": ["LeftFoot", "LeftToeBase"],
    "right_foot": ["RightFoot", "RightToeBase"], "left_hip": "LeftUpLeg", "right_hip": "RightUpLeg",
    "left_shoulder": "LeftArm", "right_shoulder": "RightArm",
    "mirror": [["Left(.+)", "Right\\1"], ["L(HipJoint|Thumb)", "R\\1"]],
}


@dataclass(frozen=True)
class ConvertedTake:
    path: Path
    source: Path
    style: str
    content: str
    standing_hips_cm: float  # the root's median height above the floor, y = 0 (cm)
    planted_toe_cm: float  # the toe joints' median height when planted (< 1 cm a frame), the floor they stand on


def cmu_clip(clip: Clip) -> Clip:
    """A Bandai-Namco clip (cm) on the CMU-style rig, same poses, still in cm."""
    src = clip.skeleton
    names = [n for n, _, _ in CMU_JOINTS]
    parents, offsets = [], []
    frames = clip.num_frames
    rotations = torch.zeros(frames, len(names), 4, dtype=clip.rotations.dtype)
    rotations[..., 3] = 1.0
    for k, (name, parent, source) in enumerate(CMU_JOINTS):
        parents.append(-1 if parent is None else names.index(parent))
        if source == "finger":
            offsets.append((FINGER_CM, 0.0, 0.0) if name.startswith("Left") else (-FINGER_CM, 0.0, 0.0))
        elif source is None or k == 0:
            offsets.append((0.0, 0.0, 0.0))
        else:
            offsets.append(src.offsets[src.index(source)])
        if source is not None and source != "finger":
            rotations[:, k] = clip.rotations[:, src.index(source)]
    ends = ((names.index("Head"), (10.0, 0.0, 0.0)), (names.index("LeftToeBase"), (5.0, 0.0, 0.0)),
            (names.index("RightToeBase"), (5.0, 0.0, 0.0)), (names.index("LeftHandIndex1"), (3.0, 0.0, 0.0)),
            (names.index("RightHandIndex1"), (-3.0, 0.0, 0.0)), (names.index("LThumb"), (2.0, 0.0, 2.0)),
            (names.index("RThumb"), (-2.0, 0.0, 2.0)))
    skeleton = Skeleton.build(names, parents, offsets, profile=SkeletonProfile.from_dict(CMU_PROFILE), end_sites=ends)
    return Clip(skeleton, rotations, clip.root_positions.clone(), clip.fps, clip.name)


def scaled(clip: Clip, cm_per_unit: float) -> Clip:
    """The clip with every length divided by ``cm_per_unit`` (cm to the file's units)."""
    from model.motion.rig_facts import scale_clip

    return scale_clip(clip, 1.0 / cm_per_unit)


def convert_takes(sources: list[tuple[Path, str, str]], out: Path, units: str = "inch",
                  fps: float = 120.0, frames: int | None = None) -> list[ConvertedTake]:
    """Write each ``(Bandai-Namco BVH, style, content)`` on the CMU-style rig under ``out`` as
    ``take_NN.bvh`` (no labels in the name) in ``units`` at ``fps``, and ``out/manifest.csv``; ``frames``: only
    the first that many frames of each source take (at its own rate; None: all)."""
    out.mkdir(parents=True, exist_ok=True)
    scale = CM_PER_UNIT[units]
    converted = []
    for n, (source, style, content) in enumerate(sources):
        clip = cmu_clip(load_clip(source, profile="bandai-namco", dtype=torch.float64))
        if frames is not None:
            clip = clip.window(0, min(frames, clip.num_frames))
        positions = clip.global_positions()
        toes = [clip.skeleton.roles.left_foot[-1], clip.skeleton.roles.right_foot[-1]]
        toe_speed = (positions[1:, toes] - positions[:-1, toes]).norm(dim=-1)
        planted = float(positions[1:, toes, 1][toe_speed < 1.0].median())
        standing = float(positions[:, 0, 1].median())
        path = out / f"take_{n:02d}.bvh"
        path.write_text(dump_clip(scaled(clip.resample(fps), scale), rotation_order="ZYX"))
        converted.append(ConvertedTake(path, source, style, content, standing, planted))
    with (out / "manifest.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["file", "style", "content"])
        for take in converted:
            writer.writerow([take.path.name, take.style, take.content])
    return converted

"""Common rig names (issue 64): a copy of the model's rig under Mixamo, Unreal Mannequin or CMU joint names is read
as the rig itself, through the bandai-namco profile's alias table; a rig that fits no names is told what it lacks
in the names it uses, without mirror-twin noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.motion.bvh import BvhDocument, BvhJoint
from model.motion.bvh_clip import dump_clip, to_clip
from model.motion.kinematics import forward_kinematics
from model.motion.skeleton import SkeletonError, SkeletonProfile, fit_names

SIDES = (("L", "Left", "l"), ("R", "Right", "r"))


def _sided(table: dict[str, str]) -> dict[str, str]:
    return {k.replace("{S}", s): v.replace("{Side}", side).replace("{s}", low)
            for s, side, low in SIDES for k, v in table.items()}


LIMBS = {"Shoulder_{S}": "{Side}Shoulder", "UpperArm_{S}": "{Side}Arm", "LowerArm_{S}": "{Side}ForeArm",
         "Hand_{S}": "{Side}Hand", "UpperLeg_{S}": "{Side}UpLeg", "LowerLeg_{S}": "{Side}Leg", "Foot_{S}": "{Side}Foot",
         "Toes_{S}": "{Side}ToeBase"}
MIXAMO = {"Chest": "Spine1", **_sided(LIMBS)}  # a two-joint spine: Spine, Spine1 (Mixamo's Spine2 is absent)
UNREAL = {"Hips": "pelvis", "Spine": "spine_01", "Chest": "spine_02", "Neck": "neck_01", "Head": "head",
          **_sided({"Shoulder_{S}": "clavicle_{s}", "UpperArm_{S}": "upperarm_{s}", "LowerArm_{S}": "lowerarm_{s}",
                    "Hand_{S}": "hand_{s}", "UpperLeg_{S}": "thigh_{s}", "LowerLeg_{S}": "calf_{s}",
                    "Foot_{S}": "foot_{s}", "Toes_{S}": "ball_{s}"})}
CMU = {"Chest": "Spine1", **_sided(LIMBS)}


def _walk() -> BvhDocument:
    return BvhDocument.parse(dump_clip(synthetic_walk(20, turn_deg_s=20.0)))


def _renamed(doc: BvhDocument, names: dict[str, str], prefix: str = "") -> BvhDocument:
    return BvhDocument([dataclasses.replace(j, name=prefix + names.get(j.name, j.name)) for j in doc.joints],
                       doc.frame_time, doc.motion)


def _above_root(doc: BvhDocument) -> BvhDocument:
    """An Unreal export: a ``root`` joint at the origin, without channels, above the pelvis."""
    joints = [BvhJoint("root", -1, (0.0, 0.0, 0.0))]
    joints += [dataclasses.replace(j, parent=j.parent + 1) for j in doc.joints]
    return BvhDocument(joints, doc.frame_time, doc.motion)


def _hip_helpers(doc: BvhDocument) -> BvhDocument:
    """A CMU export: LHipJoint / RHipJoint between the hips and each upper leg, holding its offset, no channels."""
    joints: list[BvhJoint] = []
    new_index: dict[int, int] = {}
    for i, j in enumerate(doc.joints):
        parent = new_index.get(j.parent, -1)
        if j.name in ("LeftUpLeg", "RightUpLeg"):
            joints.append(BvhJoint(f"{j.name[0]}HipJoint", parent, j.offset))
            parent, j = len(joints) - 1, dataclasses.replace(j, offset=(0.0, 0.0, 0.0))
        new_index[i] = len(joints)
        joints.append(dataclasses.replace(j, parent=parent))
    return BvhDocument(joints, doc.frame_time, doc.motion)


def _world(clip) -> torch.Tensor:
    return forward_kinematics(clip.rotations, clip.root_positions, clip.skeleton.offsets_tensor(clip.rotations.dtype),
                              clip.skeleton.parents)[0]


@pytest.mark.parametrize("rig", ["mixamo", "mixamorig-prefixed", "unreal", "cmu"])
def test_a_copy_of_the_rig_under_common_names_reads_as_the_rig(rig: str) -> None:
    doc = _walk()
    copy = {"mixamo": lambda: _renamed(doc, MIXAMO), "mixamorig-prefixed": lambda: _renamed(doc, MIXAMO, "mixamorig:"),
            "unreal": lambda: _above_root(_renamed(doc, UNREAL)), "cmu": lambda: _hip_helpers(_renamed(doc, CMU))}[rig]()
    with pytest.raises(SkeletonError):  # the profile's own names do not fit it ...
        to_clip(copy, profile=dataclasses.replace(SkeletonProfile.load("bandai-namco"), aliases=()))
    ours, theirs = to_clip(doc, profile="bandai-namco"), to_clip(copy)  # ... its aliases do, found without a profile
    assert theirs.skeleton.roles.profile == "bandai-namco"
    index = [theirs.skeleton.names.index(name) for name in ours.skeleton.names]  # every joint, by the rig's own name
    assert torch.allclose(_world(theirs)[:, index], _world(ours), atol=1e-3)
    assert np.allclose(theirs.fps, ours.fps)


def test_names_that_already_fit_are_left_alone() -> None:
    prof = SkeletonProfile.load("bandai-namco")
    names = _walk().names
    assert fit_names(names, prof) == (names, None)
    renamed, scheme = fit_names(tuple("mixamorig:" + MIXAMO.get(n, n) for n in names), prof)
    assert scheme is not None and scheme.name == "Mixamo"
    assert renamed == names  # the profile's spelling, prefix dropped


def _chain(*names: str) -> str:
    """A chain of joints, each 10 cm below its parent, one frame."""
    lines, depth = ["HIERARCHY"], 0
    for n, name in enumerate(names):
        pad = " " * depth
        lines += [f"{pad}{'ROOT' if n == 0 else 'JOINT'} {name}", f"{pad}{{", f"{pad} OFFSET 0 {0 if n == 0 else -10} 0",
                  f"{pad} CHANNELS {6 if n == 0 else 3} " + ("Xposition Yposition Zposition " if n == 0 else "") +
                  "Zrotation Xrotation Yrotation"]
        depth += 1
    lines += [" " * depth + "End Site", " " * depth + "{", " " * depth + " OFFSET 0 -10 0", " " * depth + "}"]
    lines += [" " * d + "}" for d in range(depth - 1, -1, -1)]
    lines += ["MOTION", "Frames: 1", "Frame Time: 0.0333333", " ".join(["0"] * (3 + 3 * len(names)))]
    return "\n".join(lines) + "\n"


def test_a_rig_that_fits_no_names_is_told_what_it_lacks_in_its_own() -> None:
    """Issue 64: an unrelated 3-joint rig got the hint 'thigh_R (mirror of thigh_l)'."""
    with pytest.raises(SkeletonError) as info:
        to_clip(BvhDocument.parse(_chain("pelvis", "thigh_l", "calf_l")), profile="bandai-namco")
    message = str(info.value)
    assert "mirror of" not in message, message
    assert "Its names look like Unreal Mannequin names (pelvis, thigh_l, calf_l), which this profile also reads: " \
           "under them it lacks head, foot_l, ball_l, foot_r, ball_r, thigh_r, upperarm_l, upperarm_r." in message
    with pytest.raises(SkeletonError) as info:
        to_clip(BvhDocument.parse(_chain("Root", "Bone1", "Bone2")))
    message = str(info.value)
    assert "mirror of" not in message and "It also reads Mixamo, Unreal Mannequin, CMU names" in message, message
    # A rig that has every role but a mirror twin is still told the twin.
    names = tuple(n for n in _walk().names if n != "Hand_R")
    with pytest.raises(SkeletonError, match=r"Hand_R \(mirror of Hand_L\)"):
        fit_names(names, SkeletonProfile.load("bandai-namco"))

"""Skeleton roles come from names through profiles."""

from __future__ import annotations

import json

import pytest

from model.data.synthetic import synthetic_skeleton
from model.motion.skeleton import Skeleton, SkeletonError, SkeletonProfile, detect_roles


def test_roles_from_names():
    sk = synthetic_skeleton()
    names = [sk.names[i] for i in sk.feet]
    assert names == ["Foot_L", "Toes_L", "Foot_R", "Toes_R"]
    assert sk.names[sk.roles.root] == "Hips"
    assert sk.names[sk.roles.head] == "Head"
    for j, m in enumerate(sk.mirror):
        assert sk.mirror[m] == j
        a, b = sk.names[j], sk.names[m]
        if a.endswith("_L"):
            assert b == a[:-2] + "_R"
        elif not a.endswith("_R"):
            assert a == b


def test_namespace_and_case_are_ignored():
    sk = synthetic_skeleton()
    names = tuple(f"rig:{n.upper()}" for n in sk.names)
    roles = detect_roles(names)
    assert roles.left_foot == sk.roles.left_foot
    assert roles.mirror == sk.roles.mirror


def test_missing_joints_are_named():
    sk = synthetic_skeleton()
    names = tuple(n for n in sk.names if n not in ("Toes_L", "Head"))
    with pytest.raises(SkeletonError) as err:
        detect_roles(names, "bandai-namco")
    assert "Toes_L" in str(err.value) and "Head" in str(err.value)


def test_unpaired_left_joint_is_reported():
    sk = synthetic_skeleton()
    names = tuple("Extra_L" if n == "Hand_R" else n for n in sk.names)
    with pytest.raises(SkeletonError, match="Hand_R"):
        detect_roles(names, "bandai-namco")


def test_no_builtin_profile_fits():
    with pytest.raises(SkeletonError, match="no built-in skeleton profile"):
        detect_roles(("a", "b", "c"))


def test_100style_profile():
    names = ("Hips", "LeftHip", "LeftKnee", "LeftAnkle", "LeftToe", "RightHip", "RightKnee", "RightAnkle",
             "RightToe", "Chest", "Chest2", "Chest3", "Chest4", "Neck", "Head", "LeftCollar", "LeftShoulder",
             "LeftElbow", "LeftWrist", "RightCollar", "RightShoulder", "RightElbow", "RightWrist")
    roles = detect_roles(names)
    assert roles.profile == "100style"
    assert [names[i] for i in roles.left_foot + roles.right_foot] == ["LeftAnkle", "LeftToe", "RightAnkle", "RightToe"]
    assert names[roles.mirror[names.index("LeftElbow")]] == "RightElbow"


def test_user_profile_file(tmp_path):
    prof = SkeletonProfile.load("bandai-namco").to_dict()
    prof.update(name="my-rig", head="Neck")
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(prof))
    sk = synthetic_skeleton()
    roles = detect_roles(sk.names, path)
    assert roles.profile == "my-rig" and sk.names[roles.head] == "Neck"


def test_bad_profiles(tmp_path):
    with pytest.raises(SkeletonError, match="no skeleton profile"):
        SkeletonProfile.load("nope")
    bad = tmp_path / "bad.json"
    bad.write_text('{"name": "x"}')
    with pytest.raises(SkeletonError, match="lacks"):
        SkeletonProfile.load(bad)
    bad.write_text("{not json")
    with pytest.raises(SkeletonError, match="invalid JSON"):
        SkeletonProfile.load(bad)


def test_json_round_trip(tmp_path):
    sk = synthetic_skeleton()
    sk.save(tmp_path / "skeleton.json")
    assert Skeleton.load(tmp_path / "skeleton.json") == sk


def test_structure_errors():
    sk = synthetic_skeleton()
    with pytest.raises(SkeletonError, match="topological"):
        Skeleton(names=("a", "b"), parents=(1, -1), offsets=((0, 0, 0), (0, 0, 0)), roles=sk.roles)

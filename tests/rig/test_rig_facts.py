"""Rig facts checked on import (units, facing), dropped joints, case-insensitive mirror rules and the
profile guess, on the CMU-style rig made from the Bandai-Namco fixture (no real data needed)."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.data.takes import index_takes
from model.motion.bvh import BvhDocument
from model.motion.bvh_clip import dump_clip, to_clip
from model.motion.profile_guess import guess_profile, mirror_rules
from model.motion.rig_facts import UnitsError, cm_per_unit, conform_clip, parse_units
from model.motion.skeleton import SkeletonError, SkeletonProfile, resolve_roles
from tests.rig.cmu_rig import CMU_PROFILE, cmu_clip, scaled


@pytest.fixture(scope="module")
def source():
    """A synthetic walk on the Bandai-Namco rig (cm, standing)."""
    return synthetic_walk(frames=60).to(torch.float64)


@pytest.fixture(scope="module")
def cmu_doc(source):
    return BvhDocument.parse(dump_clip(scaled(cmu_clip(source), 2.54), rotation_order="ZYX"))


def test_units_are_read_from_the_head_height_or_refused_with_the_fix():
    assert [cm_per_unit("auto", h) for h in (1.6, 63.0, 160.0, 1600.0)] == [100.0, 2.54, 1.0, 0.1]
    with pytest.raises(UnitsError, match=r"--units 6\.96"):  # a CMU take: 23 units high
        cm_per_unit("auto", 23.0)
    assert cm_per_unit(5.64, 23.0) == 5.64 and parse_units("5.64") == 5.64 and parse_units("Inches") == "inch"
    with pytest.raises(UnitsError, match="no human"):
        cm_per_unit("cm", 23.0)
    with pytest.raises(UnitsError):
        parse_units("furlongs")


def test_a_take_in_inches_is_converted_to_centimetres(source, cmu_doc):
    profile = SkeletonProfile.from_dict(CMU_PROFILE)
    clip, facts = conform_clip(to_clip(cmu_doc, profile, dtype=torch.float64))
    assert facts.cm_per_unit == 2.54 and clip.skeleton.units == "cm"
    # Same poses as the centimetre source: the helpers carry no offset and no rotation.
    want = source.global_positions()
    got = clip.global_positions()[:, [clip.skeleton.index(n) for n in ("Hips", "LeftFoot", "Head", "RightHand")]]
    ref = want[:, [source.skeleton.index(n) for n in ("Hips", "Foot_L", "Head", "Hand_R")]]
    assert torch.allclose(got, ref, atol=1e-3)


def test_facing_joints_that_share_a_point_are_refused(cmu_doc):
    trap = SkeletonProfile.from_dict({**CMU_PROFILE, "left_hip": "LHipJoint", "right_hip": "RHipJoint"})
    with pytest.raises(SkeletonError, match="LHipJoint and RHipJoint .* share a point.*LeftUpLeg and RightUpLeg"):
        conform_clip(to_clip(cmu_doc, trap, dtype=torch.float64))


def test_dropped_helpers_and_fingers_fold_into_their_children_exactly(cmu_doc):
    full = to_clip(cmu_doc, SkeletonProfile.from_dict(CMU_PROFILE), dtype=torch.float64)
    dropping = SkeletonProfile.from_dict({**CMU_PROFILE, "drop": ["[LR]HipJoint", "LowerBack", "Neck1",
                                                                   "(Left|Right)(FingerBase|HandIndex1)", "[lr]thumb"]})
    small = to_clip(cmu_doc, dropping, dtype=torch.float64)
    assert small.skeleton.num_joints == 21 and "LThumb" not in small.skeleton.names
    assert small.skeleton.parents[small.skeleton.index("LeftUpLeg")] == 0
    keep = [full.skeleton.index(n) for n in small.skeleton.names]
    assert torch.allclose(small.global_positions(), full.global_positions()[:, keep], atol=1e-6)
    with pytest.raises(SkeletonError, match="drops joint.*it gives a role"):
        to_clip(cmu_doc, SkeletonProfile.from_dict({**CMU_PROFILE, "drop": ["LeftArm"]}))


def test_mirror_rules_match_names_ignoring_case_in_order():
    names = ("hips", "lefthand", "RIGHTHAND", "LHipJoint", "rhipjoint", "LowerBack")
    profile = SkeletonProfile.from_dict({**CMU_PROFILE, "root": "hips", "head": "lowerback",
                                         "left_foot": ["lefthand"], "right_foot": ["righthand"],
                                         "left_hip": "lhipjoint", "right_hip": "RHipJoint",
                                         "left_shoulder": "lefthand", "right_shoulder": "righthand"})
    assert resolve_roles(names, profile).mirror == (0, 2, 1, 4, 3, 5)
    # A bare one-letter rule would catch LowerBack: the guess spells those joints out.
    rules, pairs = mirror_rules(list(names))
    assert rules == [["Left(.+)", "Right\\1"], ["L(HipJoint)", "R\\1"]] and pairs == {1: 2, 3: 4}


def test_the_guess_finds_the_roles_apart_and_drops_fingers_and_still_helpers(cmu_doc):
    guess = guess_profile(cmu_doc, "cmu")
    p = guess.profile
    assert guess.undecided == []
    assert (p["left_hip"], p["right_hip"], p["left_shoulder"], p["right_shoulder"]) == (
        "LeftUpLeg", "RightUpLeg", "LeftArm", "RightArm")
    assert (p["root"], p["head"], p["left_foot"]) == ("Hips", "Head", ["LeftFoot", "LeftToeBase"])
    assert set(p["drop"]) == {"LHipJoint", "RHipJoint", "LowerBack", "Neck1", "LeftFingerBase", "LeftHandIndex1",
                              "LThumb", "RightFingerBase", "RightHandIndex1", "RThumb"}
    clip = to_clip(cmu_doc, SkeletonProfile.from_dict(p))
    assert clip.skeleton.num_joints == 21


def test_a_guess_says_what_it_could_not_decide(source):
    doc = BvhDocument.parse(dump_clip(source).replace("Foot_L", "Ankle_L").replace("Foot_R", "Ankle_R")
                            .replace("Hand_", "Paw_"))
    guess = guess_profile(doc)
    assert any(u.startswith("left_shoulder/right_shoulder") for u in guess.undecided), guess.undecided
    assert guess.profile["left_foot"] == ["Ankle_L", "Toes_L"]


def test_an_empty_split_names_its_cause(tmp_path, source):
    from model.data.preprocessed import load_motion_cache
    from model.train.empty_split import empty_split_message

    data = tmp_path / "takes"
    data.mkdir()
    # The CMU rig with thighs of other names: the bandai-namco profile reads CMU names (its aliases), not these.
    text = dump_clip(scaled(cmu_clip(source), 2.54)).replace("LeftUpLeg", "LThigh").replace("RightUpLeg", "RThigh")
    (data / "walk.bvh").write_text(text)
    cache = load_motion_cache(data, root=tmp_path / "cache", progress=False)
    message = empty_split_message(cache, cache.make_split(), data, None)
    assert "not follow dataset-<N>" in message and "--manifest CSV" in message
    manifest = data / "m.csv"
    manifest.write_text("file,style,content\nnothere.bvh,proud,walk\n")
    cache = load_motion_cache(data, manifest=manifest, root=tmp_path / "cache", progress=False)
    assert "matched no file" in empty_split_message(cache, cache.make_split(), data, manifest)
    (data / "m.csv").write_text("file,style,content\nwalk.bvh,proud,walk\n")
    cache = load_motion_cache(data, manifest=manifest, root=tmp_path / "cache", progress=False)
    assert [p.kind for p in cache.problems] == ["rig"]  # no built-in profile fits the rig
    assert "rsmt profile guess" in empty_split_message(cache, cache.make_split(), data, manifest)
    assert index_takes(data, manifest).takes

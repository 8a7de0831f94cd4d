"""Motion payloads to clips and back: BVH and JSON poses agree, joints map by name, limits hold, errors name the spot."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.motion.bvh import BvhDocument
from service.errors import ServiceError
from service.motion import MotionLimits, frames_bvh, frames_json, motion_to_clip
from service.schemas import BvhMotion, PoseMotion
from tests.model.motion.bvh_strategies import ANY_BVH_TEXT
from tests.service.conftest import bvh, poses, walk

LIMITS = MotionLimits(max_frames=300, quaternion_tolerance=1e-2, max_abs_position=1e6)


@pytest.fixture(scope="module")
def engine(bundle_dir) -> Engine:
    return Engine(Bundle.load(bundle_dir), threads=1)


def convert(engine: Engine, payload: dict, limits: MotionLimits = LIMITS):
    model = BvhMotion(**payload) if "bvh" in payload else PoseMotion(**payload)
    return motion_to_clip(model, engine, limits, "clip")


def error(engine: Engine, payload: dict, limits: MotionLimits = LIMITS) -> ServiceError:
    with pytest.raises(ServiceError) as info:
        convert(engine, payload, limits)
    return info.value


def test_bvh_and_poses_give_the_same_clip(engine):
    clip = walk(45, turn_deg_s=30.0)
    a, b = convert(engine, bvh(clip)), convert(engine, poses(clip))
    assert a.num_frames == b.num_frames == 45 and a.fps == b.fps == 30
    assert torch.allclose(a.rotations, b.rotations, atol=1e-5) and torch.allclose(a.root_positions, b.root_positions, atol=1e-3)
    assert engine.style_id(a) == engine.style_id(b)


def test_other_fps_is_resampled(engine):
    clip = walk(61)
    doc = BvhDocument.parse(bvh(clip)["bvh"])
    doc.frame_time = 1 / 60  # the same frames declared at 60 fps last half as long
    out = convert(engine, {"bvh": doc.format()})
    assert out.num_frames == 31
    p = poses(clip) | {"fps": 15.0}
    assert convert(engine, p).num_frames == 121


def test_joint_order_by_name(engine):
    clip = walk(12)
    order = np.random.default_rng(0).permutation(21)
    names = [engine.skeleton.names[j] for j in order]
    payload = {"root_positions": clip.root_positions.tolist(), "rotations": clip.rotations[:, order].tolist(),
               "joints": names + []}
    assert torch.allclose(convert(engine, payload).rotations, convert(engine, poses(clip)).rotations, atol=1e-6)
    extra = {"root_positions": clip.root_positions.tolist(),
             "rotations": [r + [[0.0, 0.0, 0.0, 1.0]] for r in clip.rotations[:, order].tolist()],
             "joints": names + ["Prop"]}
    assert convert(engine, extra).num_frames == 12  # extra joints are ignored


def test_errors_name_the_problem(engine):
    clip = walk(12)
    p = poses(clip)
    rot = np.array(p["rotations"])
    rot[4, 9] *= 1.5
    e = error(engine, {**p, "rotations": rot.tolist()})
    assert e.code == "bad_motion" and "frame 4" in e.message and "joint 9 ('Shoulder_R')" in e.message
    rot = np.array(p["rotations"])
    rot[2, 3, 0] = np.nan
    e = error(engine, {**p, "rotations": rot.tolist()})
    assert e.code == "bad_motion" and "frame 2" in e.message and "Neck" in e.message
    far = np.array(p["root_positions"])
    far[0, 1] = 1e9
    assert "beyond" in error(engine, {**p, "root_positions": far.tolist()}).message
    assert error(engine, poses(walk(301))).code == "too_many_frames"
    assert error(engine, {**p, "fps": 0.05}).code in ("bad_motion", "too_many_frames")
    e = error(engine, {**p, "joints": ["Hips"] + [f"x{i}" for i in range(20)]})
    assert e.code == "skeleton_mismatch" and "Spine" in e.message
    e = error(engine, {**p, "joints": ["Hips"] * 21})
    assert e.code == "bad_motion" and "twice" in e.message


def test_bvh_errors(engine):
    assert error(engine, {"bvh": "HIERARCHY\nROOT Hips\n{\n}\nMOTION\nFrames: 0\nFrame Time: 0.03\n"}).code == "bad_motion"
    text = bvh(walk(3))["bvh"].replace("Frames: 3", "Frames: 0").rsplit("Frame Time", 1)[0] + "Frame Time: 0.0333333\n"
    assert error(engine, {"bvh": text}).code == "too_few_frames"
    deep = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n" + "".join(f"JOINT j{i}\n{{\nOFFSET 0 0 0\n" for i in range(5000))
    assert error(engine, {"bvh": deep}).code == "bad_motion"
    assert error(engine, {"bvh": "/etc/passwd"}).code == "bad_motion"  # text, never a path
    big = bvh(walk(3))["bvh"].replace("OFFSET 0.0 10.0 0.0", "OFFSET 0.0 1e12 0.0", 1)
    assert "OFFSET" in error(engine, {"bvh": big}).message
    # Non-ASCII digits ("\u0669\u0663": 93 to float()) were accepted (issue 64): a 422 naming the line and the token.
    lines = bvh(walk(3))["bvh"].split("\n")
    first = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    lines[first] = " ".join(["\u0669\u0663", *lines[first].split()[1:]])
    err = error(engine, {"bvh": "\n".join(lines)})
    assert err.code == "bad_motion" and f"clip, line {first + 1}: '\u0669\u0663' is not a number" in err.message, err


def test_output_round_trip(engine):
    clip = walk(9)
    text = frames_bvh(clip.rotations, clip.root_positions, engine.skeleton, 30.0)
    back = convert(engine, {"bvh": text})
    assert back.num_frames == 9 and torch.allclose(back.rotations, clip.rotations, atol=1e-5)
    frames = frames_json(clip.rotations, clip.root_positions)
    assert len(frames) == 9 and frames[0]["rotations"].shape == (21, 4) and frames[0]["rotations"].dtype == np.float32


# ---------------------------------------------------------------------- fuzzing the decoders of client input
_number = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(10**30), 10**30), st.just(1.0),
                    st.just(0.0), st.booleans(), st.text(max_size=4), st.none())
_quat = st.lists(_number, min_size=0, max_size=5)
_pose_json = st.fixed_dictionaries(
    {"root_positions": st.lists(st.lists(_number, max_size=4), max_size=4) | _number,
     "rotations": st.lists(st.lists(_quat, max_size=22), max_size=4) | _number},
    optional={"joints": st.lists(st.sampled_from(["Hips", "Spine", "hips", "", "x" * 300]) | st.text(max_size=5),
                                 max_size=22) | _number,
              "fps": _number, "extra": _number},
)



@st.composite
def _nearly_valid_poses(draw: st.DrawFn) -> dict:
    """Three frames of a walk with a few numbers (or whole quaternions) replaced by anything."""
    p = poses(walk(3))
    for _ in range(draw(st.integers(1, 3))):
        t, j = draw(st.integers(0, 2)), draw(st.integers(0, 20))
        quat = p["rotations"][t][j]
        if quat and draw(st.booleans()):
            quat[draw(st.integers(0, len(quat) - 1))] = draw(_number)
        elif draw(st.booleans()):
            p["rotations"][t][j] = draw(_quat)
        else:
            p["root_positions"][t][draw(st.integers(0, 2))] = draw(_number)
    return p


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(payload=_pose_json | _nearly_valid_poses() | st.dictionaries(st.text(max_size=8), _number, max_size=3))
def test_any_json_poses_decode_or_are_refused_cleanly(engine, payload):
    """JSON in (as the server reads a body): a validation error, a ServiceError with a contract code, or a clip."""
    _converts_or_is_refused(engine, PoseMotion, payload)  # NaN and Infinity as some clients write them


@settings(max_examples=100, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(text=ANY_BVH_TEXT)
def test_any_bvh_text_converts_or_is_refused_cleanly(engine, text):
    _converts_or_is_refused(engine, BvhMotion, {"bvh": text})  # a validation error: empty, or a lone surrogate


def _converts_or_is_refused(engine, kind: type[PoseMotion] | type[BvhMotion], body: object) -> None:
    """``body`` as JSON text, read as ``kind``: a validation error, a ServiceError with a contract code, or a clip
    of finite numbers."""
    try:
        motion = kind.model_validate_json(json.dumps(body))
    except ValidationError:
        return
    try:
        clip = motion_to_clip(motion, engine, LIMITS, "clip")
    except ServiceError as exc:
        assert exc.code in ("bad_motion", "skeleton_mismatch", "too_few_frames", "too_many_frames"), exc
        return
    assert torch.isfinite(clip.rotations).all() and torch.isfinite(clip.root_positions).all()


# The default rig's joints under Mixamo names (issue 64): its two spine joints as Mixamo's Spine and Spine1.
MIXAMO_NAMES = {"Chest": "Spine1", **{f"{part}_{s}": f"{side}{theirs}" for s, side in (("L", "Left"), ("R", "Right"))
                                      for part, theirs in (("Shoulder", "Shoulder"), ("UpperArm", "Arm"),
                                                           ("LowerArm", "ForeArm"), ("Hand", "Hand"), ("UpperLeg", "UpLeg"),
                                                           ("LowerLeg", "Leg"), ("Foot", "Foot"), ("Toes", "ToeBase"))}}


def test_the_default_rig_under_mixamo_names_is_served_without_a_profile():
    from model.inference.bundle import DEFAULT_BUNDLE

    engine = Engine(Bundle.load(DEFAULT_BUNDLE), threads=1)
    text = (Path(__file__).parents[2] / "clients" / "rig" / "rsmt-default-rig.bvh").read_text()
    mixamo = re.sub(r"^(\s*(?:ROOT|JOINT)\s+)(\S+)\s*$",
                    lambda m: f"{m.group(1)}mixamorig:{MIXAMO_NAMES.get(m.group(2), m.group(2))}", text, flags=re.M)
    assert "mixamorig:LeftUpLeg" in mixamo and "UpperLeg_L" not in mixamo
    ours, theirs = convert(engine, {"bvh": text}), convert(engine, {"bvh": mixamo})
    assert theirs.skeleton.names == ours.skeleton.names == engine.skeleton.names
    assert torch.allclose(theirs.rotations, ours.rotations, atol=1e-6)
    assert torch.allclose(theirs.root_positions, ours.root_positions, atol=1e-4)


def test_json_poses_may_name_their_joints_as_mixamo_does(engine):
    clip = walk(20)
    mixamo = [f"mixamorig:{MIXAMO_NAMES.get(n, n)}" for n in clip.skeleton.names]
    order = list(reversed(range(clip.skeleton.num_joints)))  # and in another order, mapped by name
    payload = {"root_positions": clip.root_positions.tolist(), "rotations": clip.rotations[:, order].tolist(),
               "joints": [mixamo[j] for j in order]}
    out = convert(engine, payload)
    assert torch.allclose(out.rotations, convert(engine, poses(clip)).rotations, atol=1e-6)
    payload["joints"] = [f"Bone{j}" for j in order]  # names of no scheme: the missing joints are named
    assert error(engine, payload).message.startswith("clip: `joints` lacks joint(s) of the model's skeleton: Hips")

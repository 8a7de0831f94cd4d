"""Motion payloads to clips and back: BVH and JSON poses agree, joints map by name, limits hold, errors name the spot."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.motion.bvh import BvhDocument
from service.errors import ServiceError
from service.motion import MotionLimits, frames_bvh, frames_json, motion_to_clip
from service.schemas import BvhMotion, PoseMotion
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


def test_output_round_trip(engine):
    clip = walk(9)
    text = frames_bvh(clip.rotations, clip.root_positions, engine.skeleton, 30.0)
    back = convert(engine, {"bvh": text})
    assert back.num_frames == 9 and torch.allclose(back.rotations, clip.rotations, atol=1e-5)
    frames = frames_json(clip.rotations, clip.root_positions)
    assert len(frames) == 9 and frames[0]["rotations"].shape == (21, 4) and frames[0]["rotations"].dtype == np.float32

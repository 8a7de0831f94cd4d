"""Features, the canonical frame, and the way back to a skeleton."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.motion.clip import Clip
from model.motion.features import (
    CanonicalFrame,
    FacingChains,
    facing_directions,
    facing_yaw,
    features_to_local,
    soft_contacts,
    temporal_rescale,
    velocities,
)
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize, quat_to_sixd
from tests.model.motion.clip_forms import clip_features
from tests.model.motion.rotation_angle import quat_angle


def test_facing_follows_walking_direction():
    for yaw in (0.0, 90.0, -135.0):
        clip = synthetic_walk(frames=10, start_yaw_deg=yaw)
        f = facing_directions(clip.global_positions()[0], clip.skeleton)
        expected = torch.tensor([math.sin(math.radians(yaw)), 0.0, math.cos(math.radians(yaw))])
        assert torch.allclose(f, expected, atol=1e-5)
        travel = clip.root_positions[-1] - clip.root_positions[0]
        assert torch.dot(travel, f) > 0


def test_canonical_frame():
    clip = synthetic_walk(frames=40, start_yaw_deg=123.0, turn_deg_s=40.0)
    feats, frame = clip_features(clip, reference_frame=9)
    sk = clip.skeleton
    f = facing_directions(feats.positions[9], sk)
    assert torch.allclose(f, torch.tensor([0.0, 0.0, 1.0]), atol=1e-5)
    root = feats.positions[9, sk.roles.root]
    assert abs(root[0]) < 1e-4 and abs(root[2]) < 1e-4
    assert torch.isclose(root[1], clip.root_positions[9, 1])
    back = frame.positions_from(feats.positions)
    assert torch.allclose(back, clip.global_positions(), atol=1e-3)


def test_canonical_frame_batched():
    clips = [synthetic_walk(frames=20, start_yaw_deg=a) for a in (0.0, 50.0, -100.0)]
    pos = torch.stack([c.global_positions() for c in clips])
    frame = CanonicalFrame.at_frame(pos, clips[0].skeleton, 5)
    assert frame.yaw.shape == (3,)
    canon = frame.positions_to(pos)
    for i, c in enumerate(clips):
        single = CanonicalFrame.at_frame(pos[i], c.skeleton, 5).positions_to(pos[i])
        assert torch.allclose(canon[i], single, atol=1e-4)


def test_features_back_to_skeleton():
    clip = synthetic_walk(frames=50, start_yaw_deg=30.0, turn_deg_s=-25.0).to(torch.float64)
    clip = replace(clip, rotations=quat_normalize(clip.rotations))  # exact unit norm in float64
    feats, frame = clip_features(clip, reference_frame=0)
    local, root = features_to_local(feats.positions, feats.rotations_6d, clip.skeleton, frame)
    sk = clip.skeleton
    pos, _ = forward_kinematics(local, root, sk.offsets_tensor(torch.float64), sk.parents)
    assert (pos - clip.global_positions()).abs().max() < 1e-6
    assert quat_angle(local, clip.rotations).max() < 1e-6


def test_velocities_and_contacts():
    pos = torch.zeros(5, 2, 3)
    pos[:, 0, 0] = torch.arange(5.0) * 2.0
    v = velocities(pos)
    assert torch.allclose(v[:, 0, 0], torch.full((5,), 2.0))
    assert torch.equal(v[:, 1], torch.zeros(5, 3))
    speeds = torch.tensor([0.0, 0.5, 0.75, 1.0, 3.0])
    c = soft_contacts(torch.stack([speeds, torch.zeros(5), torch.zeros(5)], dim=-1))
    assert torch.allclose(c, torch.tensor([1.0, 1.0, 0.5, 0.0, 0.0]))


def test_resample_60_to_30():
    clip = synthetic_walk(frames=61, fps=60.0)
    half = clip.resample(30.0)
    assert half.num_frames == 31 and half.fps == 30.0
    assert quat_angle(half.rotations, clip.rotations[::2]).max() < 1e-3
    assert torch.allclose(half.root_positions, clip.root_positions[::2], atol=1e-4)


def test_resample_between_frames():
    clip = synthetic_walk(frames=31, fps=30.0)
    up = clip.resample(60.0)
    assert up.num_frames == 61
    mid = (clip.root_positions[:-1] + clip.root_positions[1:]) / 2
    assert torch.allclose(up.root_positions[1::2], mid, atol=1e-4)


def test_temporal_rescale_is_seeded_and_bounded():
    clip = synthetic_walk(frames=60)
    a = temporal_rescale(clip, torch.Generator().manual_seed(3))
    b = temporal_rescale(clip, torch.Generator().manual_seed(3))
    assert torch.equal(a.rotations, b.rotations)
    lengths = {temporal_rescale(clip, torch.Generator().manual_seed(s)).num_frames for s in range(30)}
    assert max(lengths) <= 60 and min(lengths) >= 15 and len(lengths) > 3


def test_clip_validation():
    clip = synthetic_walk(frames=5)
    with pytest.raises(ValueError, match="rotations"):
        Clip(clip.skeleton, clip.rotations[:, :3], clip.root_positions, 30.0)
    with pytest.raises(ValueError, match="window"):
        clip.window(3, 9)
    with pytest.raises(ValueError, match="fps"):
        replace(clip, fps=0.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_facing_from_rotations_is_the_facing_of_the_posed_joints(seed):
    sk = synthetic_skeleton()
    local = quat_normalize(torch.randn(6, sk.num_joints, 4, generator=torch.Generator().manual_seed(seed)))
    pos, glob = forward_kinematics(local, torch.randn(6, 3), sk.offsets_tensor(), sk.parents)
    diff = FacingChains.of(sk).yaw(quat_to_sixd(glob)) - facing_yaw(pos, sk)
    assert torch.allclose(torch.atan2(torch.sin(diff), torch.cos(diff)), torch.zeros_like(diff), atol=1e-4)

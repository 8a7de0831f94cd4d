"""Mirroring: exact involution, reflected positions, turns change direction."""

from __future__ import annotations

from dataclasses import replace

import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.motion.features import facing_yaw
from model.motion.mirror import WORLD_MIRROR, mirror_reflections
from model.motion.rotations import quat_normalize
from tests.model.motion.clip_forms import mirror_clip
from tests.model.motion.rotation_angle import quat_angle


def test_mirror_twice_is_identity():
    clip = synthetic_walk(frames=40, turn_deg_s=30.0)
    g = torch.Generator().manual_seed(0)
    rot = quat_normalize(clip.rotations + 0.3 * torch.randn(clip.rotations.shape, generator=g))
    clip = type(clip)(clip.skeleton, rot, clip.root_positions, clip.fps)
    back = mirror_clip(mirror_clip(clip))
    assert quat_angle(back.rotations, clip.rotations).max() < 1e-5
    assert (back.root_positions - clip.root_positions).abs().max() < 1e-5


def test_mirrored_positions_are_reflected():
    clip = synthetic_walk(frames=30, turn_deg_s=45.0).to(torch.float64)
    clip = replace(clip, rotations=quat_normalize(clip.rotations))
    pos = clip.global_positions()
    mpos = mirror_clip(clip).global_positions()
    idx = torch.tensor(clip.skeleton.mirror)
    expected = pos[:, idx] @ WORLD_MIRROR.T
    assert (mpos - expected).abs().max() < 1e-6


def test_reflections_map_offsets_to_counterparts():
    sk = synthetic_skeleton()
    a = mirror_reflections(sk)
    offs = sk.offsets_tensor(torch.float64)
    assert torch.allclose(torch.det(a), -torch.ones(sk.num_joints, dtype=torch.float64))
    for j in range(sk.num_joints):
        assert torch.allclose(a[j].T @ a[j], torch.eye(3, dtype=torch.float64), atol=1e-9)
        assert torch.allclose(a[sk.mirror[j]], a[j].T, atol=1e-9)
        for c in sk.children[j]:
            assert torch.allclose(a[j] @ offs[c], offs[sk.mirror[c]], atol=1e-9)


def test_left_turn_becomes_right_turn():
    clip = synthetic_walk(frames=60, turn_deg_s=60.0)
    sk = clip.skeleton
    turn = facing_yaw(clip.global_positions()[-1], sk) - facing_yaw(clip.global_positions()[0], sk)
    mirrored = mirror_clip(clip)
    mturn = facing_yaw(mirrored.global_positions()[-1], sk) - facing_yaw(mirrored.global_positions()[0], sk)
    assert turn > 0.5
    assert torch.isclose(mturn, -turn, atol=1e-4)


def test_symmetric_rig_mirrors_with_plain_reflection():
    # The synthetic rig is symmetric at rest with identity rest rotations, so the mirror of its
    # walk must be the same walk with the legs' and arms' roles swapped: no twist anywhere.
    a = mirror_reflections(synthetic_skeleton())
    assert torch.allclose(a, WORLD_MIRROR.expand_as(a), atol=1e-9)

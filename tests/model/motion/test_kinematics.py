"""Forward kinematics and its inverse."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.motion.kinematics import (
    bone_offsets_from_positions,
    check_parents,
    forward_kinematics,
    global_to_local_rotations,
    inverse_kinematics,
)
from model.motion.rotations import axis_angle_to_quat, quat_angle, quat_identity, quat_normalize

PARENTS = (-1, 0, 1, 2, 1, 0)
OFFSETS = torch.tensor([[0, 0, 0], [0, 10, 0], [0, 10, 0], [0, 5, 0], [5, 0, 0], [0, -10, 0]], dtype=torch.float64)


def test_chain_known_values():
    rot = quat_identity((6,), torch.float64)
    # Bend joint 1 by 90 degrees about +Z: its children swing from +Y to -X.
    rot[1] = axis_angle_to_quat(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                                torch.tensor(math.pi / 2, dtype=torch.float64))
    pos, grot = forward_kinematics(rot, torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64), OFFSETS, PARENTS)
    assert torch.allclose(pos[1], torch.tensor([1.0, 12.0, 3.0], dtype=torch.float64))
    assert torch.allclose(pos[2], torch.tensor([-9.0, 12.0, 3.0], dtype=torch.float64), atol=1e-12)
    assert torch.allclose(pos[3], torch.tensor([-14.0, 12.0, 3.0], dtype=torch.float64), atol=1e-12)
    assert torch.allclose(pos[4], torch.tensor([1.0, 17.0, 3.0], dtype=torch.float64), atol=1e-12)
    assert torch.allclose(pos[5], torch.tensor([1.0, -8.0, 3.0], dtype=torch.float64))
    assert quat_angle(grot[3], rot[1]).item() < 1e-9


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_ik_inverts_fk(seed):
    g = torch.Generator().manual_seed(seed)
    rot = quat_normalize(torch.randn(3, 4, 6, 4, generator=g, dtype=torch.float64))
    root = torch.randn(3, 4, 3, generator=g, dtype=torch.float64) * 50
    pos, grot = forward_kinematics(rot, root, OFFSETS, PARENTS)
    local, root_back = inverse_kinematics(pos, grot, PARENTS)
    assert (quat_angle(local, rot) < 1e-6).all()
    assert torch.allclose(root_back, root)
    pos2, _ = forward_kinematics(local, root_back, OFFSETS, PARENTS)
    assert torch.allclose(pos2, pos, atol=1e-9)
    offs = bone_offsets_from_positions(pos, grot, PARENTS)
    assert torch.allclose(offs[..., 1:, :], OFFSETS[1:].expand_as(offs[..., 1:, :]), atol=1e-9)


def test_global_to_local_root_unchanged():
    g = quat_normalize(torch.randn(2, 6, 4, dtype=torch.float64))
    assert torch.equal(global_to_local_rotations(g, PARENTS)[:, 0], g[:, 0])


def test_per_frame_offsets_broadcast():
    rot = quat_identity((2, 6), torch.float64)
    offs = OFFSETS.expand(2, 6, 3).clone()
    offs[1] *= 2
    pos, _ = forward_kinematics(rot, torch.zeros(2, 3, dtype=torch.float64), offs, PARENTS)
    assert torch.allclose(pos[1], 2 * pos[0])


@pytest.mark.parametrize("parents", [(0, 0), (-1, 2, 0), (-1, -1)])
def test_bad_parents(parents):
    with pytest.raises(ValueError):
        check_parents(parents)

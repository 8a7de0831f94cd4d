"""The interpolation and zero-velocity baselines (model/evaluation/baselines.py)."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.evaluation.baselines import interpolate, zero_velocity
from model.motion.rotations import quat_normalize, yaw_quat
from tests.model.motion.rotation_angle import quat_angle

BASELINES = [interpolate, zero_velocity]


def make_case(b: int, j: int, seed: int, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    rot0 = quat_normalize(torch.randn(b, j, 4, generator=g, dtype=dtype))
    rot1 = quat_normalize(torch.randn(b, j, 4, generator=g, dtype=dtype))
    root0 = torch.randn(b, 3, generator=g, dtype=dtype) * 50
    root1 = torch.randn(b, 3, generator=g, dtype=dtype) * 50
    return rot0, root0, rot1, root1


@pytest.mark.parametrize("fn", BASELINES)
@pytest.mark.parametrize("frames", [1, 2, 7, 40])
def test_shapes_and_last_frame_is_the_target_exactly(fn, frames):
    rot0, root0, rot1, root1 = make_case(3, 5, seed=frames)
    rot, root = fn(rot0, root0, rot1, root1, frames)
    assert rot.shape == (3, frames, 5, 4) and root.shape == (3, frames, 3)
    assert rot.dtype == rot0.dtype and root.dtype == root0.dtype
    assert torch.equal(rot[:, -1], rot1)
    assert torch.equal(root[:, -1], root1)


@pytest.mark.parametrize("fn", BASELINES)
def test_inputs_are_not_modified(fn):
    case = make_case(2, 4, seed=0)
    copies = [t.clone() for t in case]
    fn(*case, 5)
    for a, b in zip(case, copies):
        assert torch.equal(a, b)


@pytest.mark.parametrize("fn", BASELINES)
def test_constant_pose_is_exact_at_every_frame(fn):
    rot0, root0, _, _ = make_case(2, 6, seed=1)
    rot, root = fn(rot0, root0, rot0.clone(), root0.clone(), 12)
    assert torch.equal(rot, rot0[:, None].expand_as(rot))
    assert torch.equal(root, root0[:, None].expand_as(root))


def test_interpolation_first_frame_is_one_nth_of_the_way():
    n = 8
    rot0 = yaw_quat(torch.zeros(1, 2, dtype=torch.float64))
    rot1 = yaw_quat(torch.tensor([[0.8, -1.6]], dtype=torch.float64))
    root0 = torch.tensor([[0.0, 90.0, 0.0]], dtype=torch.float64)
    root1 = torch.tensor([[80.0, 94.0, -16.0]], dtype=torch.float64)
    rot, root = interpolate(rot0, root0, rot1, root1, n)
    torch.testing.assert_close(rot[:, 0], yaw_quat(torch.tensor([[0.1, -0.2]], dtype=torch.float64)))
    torch.testing.assert_close(root[:, 0], torch.tensor([[10.0, 90.5, -2.0]], dtype=torch.float64))
    # Every frame k is k/N of the way, in angle and in root position.
    for k in range(1, n + 1):
        torch.testing.assert_close(rot[:, k - 1], yaw_quat(torch.tensor([[0.8, -1.6]], dtype=torch.float64) * k / n))
        torch.testing.assert_close(root[:, k - 1], root0 + (root1 - root0) * k / n)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), frames=st.integers(1, 20))
def test_interpolation_walks_the_shorter_arc_in_equal_steps(seed, frames):
    rot0, root0, rot1, root1 = make_case(2, 3, seed=seed, dtype=torch.float64)
    rot, _ = interpolate(rot0, root0, rot1, root1, frames)
    total = quat_angle(rot0, rot1)  # shorter-arc angle, <= pi
    for k in range(1, frames + 1):
        torch.testing.assert_close(quat_angle(rot0, rot[:, k - 1]), total * k / frames, atol=1e-7, rtol=1e-7)
        torch.testing.assert_close(quat_angle(rot[:, k - 1], rot1), total * (frames - k) / frames, atol=1e-7, rtol=1e-7)
    # Emitted frames are sign-continuous and unit length.
    if frames > 1:
        assert torch.all((rot[:, 1:] * rot[:, :-1]).sum(-1) > 0)
    torch.testing.assert_close(rot.norm(dim=-1), torch.ones(rot.shape[:-1], dtype=torch.float64))


def test_interpolation_handles_opposite_signs_of_the_same_rotation():
    rot0, root0, _, root1 = make_case(2, 3, seed=5)
    rot, _ = interpolate(rot0, root0, -rot0, root1, 6)
    assert torch.all(quat_angle(rot, rot0[:, None]) < 1e-3)
    assert torch.equal(rot[:, -1], -rot0)


def test_zero_velocity_holds_then_jumps():
    rot0, root0, rot1, root1 = make_case(2, 4, seed=2)
    rot, root = zero_velocity(rot0, root0, rot1, root1, 5)
    for k in range(4):
        assert torch.equal(rot[:, k], rot0)
        assert torch.equal(root[:, k], root0)
    assert torch.equal(rot[:, 4], rot1)
    assert torch.equal(root[:, 4], root1)


@pytest.mark.parametrize("fn", BASELINES)
def test_batched_equals_per_item(fn):
    rot0, root0, rot1, root1 = make_case(4, 5, seed=3)
    rot, root = fn(rot0, root0, rot1, root1, 9)
    for i in range(4):
        r_i, p_i = fn(rot0[i : i + 1], root0[i : i + 1], rot1[i : i + 1], root1[i : i + 1], 9)
        torch.testing.assert_close(rot[i : i + 1], r_i, rtol=0, atol=1e-7)
        torch.testing.assert_close(root[i : i + 1], p_i, rtol=0, atol=1e-5)


@pytest.mark.parametrize("fn", BASELINES)
def test_rejects_bad_arguments(fn):
    rot0, root0, rot1, root1 = make_case(2, 3, seed=4)
    for frames in (0, -1, 2.5, True):
        with pytest.raises(ValueError):
            fn(rot0, root0, rot1, root1, frames)
    with pytest.raises(ValueError):
        fn(rot0, root0, rot1[:, :2], root1, 3)
    with pytest.raises(ValueError):
        fn(rot0, root0[:1], rot1, root1, 3)
    with pytest.raises(ValueError):
        fn(rot0[0], root0, rot1[0], root1, 3)

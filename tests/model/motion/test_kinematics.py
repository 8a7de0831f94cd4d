"""Forward kinematics and its inverse."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.motion.kinematics import (
    ChainKinematics,
    check_parents,
    forward_kinematics,
    global_to_local_rotations,
    two_bone_ik,
)
from model.motion.rotations import (
    axis_angle_to_quat,
    quat_conjugate,
    quat_identity,
    quat_mul,
    quat_normalize,
    quat_rotate,
)
from tests.model.motion.rotation_angle import quat_angle

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
def test_global_to_local_inverts_fk(seed):
    g = torch.Generator().manual_seed(seed)
    rot = quat_normalize(torch.randn(3, 4, 6, 4, generator=g, dtype=torch.float64))
    root = torch.randn(3, 4, 3, generator=g, dtype=torch.float64) * 50
    pos, grot = forward_kinematics(rot, root, OFFSETS, PARENTS)
    local = global_to_local_rotations(grot, PARENTS)
    assert (quat_angle(local, rot) < 1e-6).all()
    pos2, _ = forward_kinematics(local, pos[..., 0, :], OFFSETS, PARENTS)
    assert torch.allclose(pos2, pos, atol=1e-9)


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


BIG_PARENTS = (-1, 0, 1, 2, 3, 0, 5, 6, 7, 1, 9, 10, 9)  # a root, two legs of four, a spine that forks


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.lists(st.integers(0, len(BIG_PARENTS) - 1), min_size=1, max_size=5))
def test_chain_kinematics_gives_full_forward_kinematics_of_the_joints_on_the_way(seed, ends):
    gen = torch.Generator().manual_seed(seed)
    j = len(BIG_PARENTS)
    offsets = torch.randn(j, 3, generator=gen, dtype=torch.float64) * 10
    rot = quat_normalize(torch.randn(3, j, 4, generator=gen, dtype=torch.float64))
    root = torch.randn(3, 3, generator=gen, dtype=torch.float64)
    pos, grot = forward_kinematics(rot, root, offsets, BIG_PARENTS)
    chains = ChainKinematics(BIG_PARENTS, offsets, ends)
    on_way = set()
    for e in ends:
        while e >= 0:
            on_way.add(e)
            e = BIG_PARENTS[e]
    assert sorted(chains.joints) == sorted(on_way) and chains.joints[0] == 0
    p, r = chains(rot, root)
    assert torch.allclose(p, pos[:, list(chains.joints)], atol=1e-9)
    assert torch.allclose(r, grot[:, list(chains.joints)], atol=1e-9)
    assert torch.equal(chains.pick(p, ends), p[:, chains.columns(ends)])
    with pytest.raises(ValueError):
        chains.columns([j + 1])


def _bent(new_rot: torch.Tensor, old_rot: torch.Tensor, bone: torch.Tensor) -> torch.Tensor:
    """A bone hanging from a joint whose world rotation went from ``old_rot`` to ``new_rot``."""
    return quat_rotate(quat_mul(new_rot, quat_conjugate(old_rot)), bone)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 1.6))
def test_two_bone_ik_reaches_what_it_can_and_keeps_the_bones(seed, stretch):
    gen = torch.Generator().manual_seed(seed)
    a, b, c = (torch.randn(4, 3, generator=gen, dtype=torch.float64) * 20 for _ in range(3))
    ra, rb = (quat_normalize(torch.randn(4, 4, generator=gen, dtype=torch.float64)) for _ in range(2))
    l1, l2 = (b - a).norm(dim=-1), (c - b).norm(dim=-1)
    direction = torch.nn.functional.normalize(torch.randn(4, 3, generator=gen, dtype=torch.float64), dim=-1)
    reach = (l1 - l2).abs() + stretch * (l1 + l2 - (l1 - l2).abs())  # from fully folded to 1.6x fully stretched
    target = a + reach.unsqueeze(-1) * direction
    new_a, new_b = two_bone_ik(a, b, c, ra, rb, target)
    knee = a + _bent(new_a, ra, b - a)
    end = knee + _bent(new_b, rb, c - b)
    assert torch.allclose((knee - a).norm(dim=-1), l1, atol=1e-6) and torch.allclose((end - knee).norm(dim=-1), l2, atol=1e-6)
    inside = (reach > (l1 - l2).abs() + 1e-2) & (reach < l1 + l2 - 1e-2)
    assert torch.allclose(end[inside], target[inside], atol=1e-3)
    # Out of reach: as far as the bones go, toward the target.
    out = reach >= l1 + l2
    toward = torch.nn.functional.normalize(end[out] - a[out], dim=-1)
    assert torch.allclose(toward, direction[out], atol=1e-3)


def test_kept_index_tensors_made_in_inference_mode_still_serve_autograd():
    # The engine first uses these functions under inference mode; training later backpropagates through
    # the same kept index tensors, which must not be inference tensors.
    parents = (-1, 0, 1, 1, 3, 0, 5)  # a hierarchy no other test uses, so its index is made here
    with torch.inference_mode():
        global_to_local_rotations(quat_normalize(torch.randn(2, 7, 4)), parents)
        chains = ChainKinematics(parents, torch.randn(7, 3), [4, 6])
        chains(quat_normalize(torch.randn(2, 7, 4)), torch.randn(2, 3))
    q = quat_normalize(torch.randn(2, 7, 4)).requires_grad_()
    (global_to_local_rotations(q, parents).sum() + chains(q, torch.zeros(2, 3))[0].sum()).backward()
    assert q.grad is not None and torch.isfinite(q.grad).all()

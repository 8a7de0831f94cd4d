"""A standing pose from the skeleton alone stands upright on the floor, arms down, facing +Z, whatever the rig's rest pose."""

from __future__ import annotations

import numpy as np
import pytest

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import DEFAULT_BUNDLE
from model.motion.skeleton import Skeleton
from model.motion.standing_pose import TOE_HEIGHT, Rig, axis_angle, standing_pose, t_pose


def default_rig() -> Skeleton:
    return Skeleton.load(DEFAULT_BUNDLE / "skeleton.json")


def lying_rig() -> Skeleton:
    # The synthetic rig with every bone turned 90 degrees at rest (the person lies on its side when all its
    # rotations are identities): the pose must come from the bones, not from the rest pose.
    sk = synthetic_skeleton()
    turn = axis_angle(np.array([0.0, 0.0, 1.0]), 90.0) @ axis_angle(np.array([1.0, 0.0, 0.0]), 30.0)
    return Skeleton.build(sk.names, sk.parents, (np.array(sk.offsets) @ turn.T).tolist(), profile="bandai-namco")


@pytest.mark.parametrize("make", [default_rig, synthetic_skeleton, lying_rig])
def test_the_standing_pose_is_an_upright_person_with_the_arms_down(make) -> None:
    sk = make()
    rig = Rig.from_skeleton(sk)
    r = sk.roles
    _, pos = standing_pose(rig).world(rig)
    feet = pos[list(sk.feet), 1]
    assert feet.min() == pytest.approx(TOE_HEIGHT, abs=1e-6)
    head, hips = pos[r.head, 1], pos[r.root, 1]
    leg = float(sum(np.linalg.norm(rig.offsets[j]) for j in sk.legs[0][1:]))
    assert hips == pytest.approx(feet.min() + leg, rel=0.15)          # straight legs under the hips
    assert head > hips + 30
    assert abs(pos[r.left_foot[0], 0] + pos[r.right_foot[0], 0]) < 1e-3  # symmetric about x = 0
    assert pos[r.left_hip, 0] > 0 > pos[r.right_hip, 0]               # facing +Z: the left on +X
    assert (pos[r.left_foot[1], 2] - pos[r.left_foot[0], 2]) > 0      # toes forward
    for side, sign in (("left", 1.0), ("right", -1.0)):
        shoulder = pos[getattr(r, f"{side}_shoulder")]
        hand = pos[[j for j in rig.descendants(getattr(r, f"{side}_shoulder")) if not rig.children(j)][0]]
        assert hand[1] < shoulder[1] - 30                              # hanging down...
        assert 0 < sign * (hand[0] - shoulder[0]) < 15                 # ...a little away from the body
    # The arms are all that differ from the T-pose.
    arms = {j for s in (r.left_shoulder, r.right_shoulder) for j in rig.descendants(s)}
    _, tpos = t_pose(rig).world(rig)
    others = [j for j in range(len(rig.names)) if j not in arms]
    np.testing.assert_allclose(pos[others], tpos[others], atol=1e-9)

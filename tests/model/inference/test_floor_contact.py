"""Floor contact: a body whose feet sink under its context's floor is lifted onto it, and only then."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_walk
from model.inference.output.floor_contact import FloorContact, FloorStep
from model.inference.output.foot_lock import FootLock
from model.inference.output.pipeline import FrameSteps
from model.inference.output.settings import OutputConfig
from model.inference.traced_step import CompiledFrameOutput
from model.motion.kinematics import ChainKinematics, feet_kinematics, forward_kinematics
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import state_from_positions


@pytest.fixture(scope="module")
def walk():
    return synthetic_walk(frames=30)


def test_foot_heights_are_those_of_full_forward_kinematics(walk) -> None:
    sk = walk.skeleton
    pos, _ = forward_kinematics(walk.rotations, walk.root_positions, sk.offsets_tensor(), sk.parents)
    heights = FloorContact(sk).foot_heights(walk.rotations, walk.root_positions)
    assert torch.allclose(heights, pos[:, list(sk.feet), 1], atol=1e-4)


@settings(max_examples=30, deadline=None)
@given(st.floats(-30.0, 30.0), st.integers(0, 29))
def test_a_sunk_body_is_lifted_to_the_tolerance_and_a_raised_one_left_alone(drop, frame) -> None:
    walk = synthetic_walk(frames=30)
    floor = FloorContact(walk.skeleton)
    ground = floor.floor(walk.rotations, walk.root_positions)
    rot, root = walk.rotations[frame:frame + 1], walk.root_positions[frame:frame + 1].clone()
    root[:, 1] -= drop  # sink (drop > 0) or raise the body
    lifted = floor.lift(rot, root, ground)
    lowest = floor.foot_heights(rot, lifted).min()
    assert lowest >= ground - floor.tolerance - 1e-3  # never more than the tolerance under the floor
    assert torch.equal(lifted[:, [0, 2]], root[:, [0, 2]])  # only ever up
    assert lifted[0, 1] >= root[0, 1]
    if floor.foot_heights(rot, root).min() >= ground - floor.tolerance:
        assert torch.equal(lifted, root)  # feet on or above the floor: untouched
    else:
        assert lowest == pytest.approx(float(ground) - floor.tolerance, abs=1e-3)  # lifted just enough


def test_the_traced_way_out_lifts_as_eager_does(walk) -> None:
    sk = walk.skeleton
    rot = torch.stack([walk.rotations, walk.rotations], 1)  # [T, 2, J, 4]: one character sinks, one does not
    root = torch.stack([walk.root_positions, walk.root_positions], 1).clone()
    root[10:, 0, 1] -= torch.linspace(0.0, 12.0, 20)
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.transpose(0, 1), quat_to_sixd(grot).transpose(0, 1), sk.roles.root)
    floor = FloorContact(sk)
    output = FrameSteps(sk, {"floor_contact": FloorStep(floor)})
    assert "floor" in output.keys
    traced = CompiledFrameOutput(output)
    yaw, origin = torch.zeros(2), torch.zeros(2, 3)

    def run(fn) -> torch.Tensor:
        mem = {"prev_rot": rot[9], "prev_root": root[9],
               "floor": torch.cat([floor.floor(rot[:10, i], root[:10, i]) for i in range(2)]),
               "lift_cap": torch.tensor([math.inf, 12.0])}  # one character uncapped, one lowered past 12 cm
        roots = []
        for t in range(10, 30):
            _, r, mem = fn(states.index((slice(None), t)), yaw, origin, torch.full((2,), 29 - t), mem)
            roots.append(r)
        return torch.stack(roots)

    eager_roots, traced_roots = run(output), run(traced)
    assert traced._graph is not None
    assert torch.allclose(eager_roots, traced_roots, atol=1e-4)
    assert (eager_roots[:, 0, 1] - root[10:, 0, 1]).max() > 4.0  # the sinking one was lifted ...
    assert torch.allclose(eager_roots[:, 1], root[10:, 1], atol=1e-4)  # ... the other left alone


def test_the_setting_round_trips_and_is_off_by_default() -> None:
    assert OutputConfig().floor is False
    on = OutputConfig(floor=True)
    assert OutputConfig.from_dict(on.to_dict()) == on
    assert on.with_overrides(floor=False).floor is False and OutputConfig().with_overrides(floor=True).floor
    with pytest.raises(ValueError, match="tolerance"):
        FloorContact(synthetic_walk(frames=5).skeleton, tolerance_cm=-1.0)


def test_a_kinematics_object_that_does_not_reach_the_feet_is_refused() -> None:
    # Floor contact and the foot lock may be given one kinematics object to share; one built for
    # other end joints (here the head's chain) would give them the wrong joints' heights.
    sk = synthetic_walk(frames=5).skeleton
    head = ChainKinematics(sk.parents, sk.offsets_tensor(), [sk.roles.head])
    with pytest.raises(ValueError, match="not on the way"):
        FloorContact(sk, kinematics=head)
    with pytest.raises(ValueError, match="not on the way"):
        FootLock(sk, 30.0, kinematics=head)
    legs = feet_kinematics(sk)
    assert FloorContact(sk, kinematics=legs).kinematics is FootLock(sk, 30.0, kinematics=legs).kinematics

"""model.inference.placed_target: the pose a ``target_at`` arrives in stands on the place, faces as asked, and is
the context's last pose otherwise."""

from __future__ import annotations

import math

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.placed_target import Placement, placed_target
from model.motion.features import facing_yaw


@pytest.mark.parametrize("yaw", [0.0, 90.0, -135.0, 179.0])
def test_the_placed_pose_stands_on_the_place_facing_as_asked(yaw: float) -> None:
    context = synthetic_walk(frames=20, start_yaw_deg=30.0, turn_deg_s=25.0).to(torch.float64)
    target = placed_target(context, Placement(x=-120.0, z=340.0, yaw_deg=yaw))
    assert target.num_frames == 1 and target.skeleton == context.skeleton
    root = target.root_positions[0]
    assert (float(root[0]), float(root[2])) == (-120.0, 340.0)
    assert float(root[1]) == float(context.root_positions[-1, 1])  # the height kept
    facing = math.degrees(float(facing_yaw(target.global_positions()[0], target.skeleton)))
    assert abs((facing - yaw + 180.0) % 360.0 - 180.0) < 1e-4
    # Only the root turns: every other joint keeps its local rotation, so the pose is the context's last one.
    torch.testing.assert_close(target.rotations[0, 1:], context.rotations[-1, 1:], rtol=0, atol=0)
    before = context.global_positions()[-1] - context.root_positions[-1]
    after = target.global_positions()[0] - target.root_positions[0]
    torch.testing.assert_close(before.norm(dim=-1), after.norm(dim=-1), rtol=0, atol=1e-4)


def test_a_placement_needs_finite_numbers() -> None:
    with pytest.raises(ValueError, match="finite"):
        Placement(x=float("nan"), z=0.0, yaw_deg=0.0)

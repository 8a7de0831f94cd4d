"""Feet below the floor: the deepest a foot joint goes under its ground level, per sequence."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.evaluation.floor import floor_depth


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 30.0), st.floats(-20.0, 20.0), st.integers(1, 12))
def test_the_depth_is_how_far_the_lowest_foot_sinks_and_never_negative(sink, ground, frames) -> None:
    pos = torch.zeros(2, frames, 4, 3)
    pos[..., 1] = ground + 5.0  # every joint 5 cm above the ground
    pos[0, frames // 2, 2, 1] = ground - sink  # one foot joint of sequence 0 sinks on one frame
    depth = floor_depth(pos, [1, 2], [ground, ground])
    assert depth[0].item() == pytest.approx(sink, abs=1e-4)
    assert depth[1].item() == 0.0  # above the floor: 0, not negative
    assert floor_depth(pos, [3], [ground]).tolist() == [0.0, 0.0]  # a joint that stays up


def test_each_joint_has_its_own_ground_and_bad_shapes_are_refused() -> None:
    pos = torch.zeros(1, 3, 2, 3)
    pos[..., 0, 1], pos[..., 1, 1] = 10.0, 3.0  # ankle 10 cm, toe 3 cm
    assert floor_depth(pos, [0, 1], [11.7, 4.25]).item() == pytest.approx(1.7)
    with pytest.raises(ValueError, match="levels"):
        floor_depth(pos, [0, 1], [1.0])
    with pytest.raises(ValueError, match="at least one frame"):
        floor_depth(torch.zeros(1, 0, 2, 3), [0], [0.0])

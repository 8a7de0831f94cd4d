"""Exact arrival: the last frame is the target, earlier frames untouched, planted feet held."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.output.arrival import arrival_weight, exact_arrival
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import axis_angle_to_quat
from tests.model.motion.rotation_angle import quat_angle


def test_weight_schedule():
    w = arrival_weight(torch.tensor([20, 10, 5, 1, 0]), 10)
    assert w[0] == 0 and w[1] == 0 and w[-1] == 1
    assert 0 < w[2] < w[3] < 1


def test_last_frame_is_the_target_and_early_frames_are_untouched():
    walk = synthetic_walk(frames=60, turn_deg_s=20.0)
    gen_rot, gen_root = walk.rotations[:40], walk.root_positions[:40]
    # A target 30 cm off to the side of where the motion ends.
    target_rot = walk.rotations[45]
    target_root = walk.root_positions[45] + torch.tensor([30.0, 0.0, 0.0])
    rot, root = exact_arrival(gen_rot, gen_root, target_rot, target_root, walk.skeleton, window=10)
    assert quat_angle(rot[-1], target_rot).max() < 1e-5
    assert torch.allclose(root[-1], target_root, atol=1e-5)
    assert torch.equal(rot[:29], gen_rot[:29]) and torch.equal(root[:29], gen_root[:29])


def _ankle_slide(rot, root, sk, frames):
    pos, _ = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    ankles = pos[:, [sk.roles.left_foot[0], sk.roles.right_foot[0]]]
    return (ankles[1:] - ankles[:-1]).norm(dim=-1)[-frames:].sum().item()


def test_a_planted_foot_stays_while_the_swinging_foot_takes_the_correction():
    walk = synthetic_walk(frames=40)
    sk = walk.skeleton
    rot, root = walk.rotations.clone(), walk.root_positions.clone()
    # Standing, knees bent; the right leg swings forward and back during the last frames while
    # the left foot stays planted. The motion ends 4 cm short of the target.
    rot[:] = rot[0]
    root[:] = root[0]
    ex = torch.tensor([1.0, 0.0, 0.0])
    for side in ("L", "R"):
        rot[:, sk.index(f"UpperLeg_{side}")] = axis_angle_to_quat(ex, torch.tensor(-0.35))
        rot[:, sk.index(f"LowerLeg_{side}")] = axis_angle_to_quat(ex, torch.tensor(0.7))
    swing = 0.4 * torch.sin(torch.linspace(0, 3.14159, 12))
    rot[26:38, sk.index("UpperLeg_R")] = axis_angle_to_quat(ex.expand(12, 3), -0.35 - swing)
    target_root = root[0] + torch.tensor([0.0, 0.0, 4.0])
    out_rot, out_root = exact_arrival(rot, root, rot[-1], target_root, sk, window=12)
    assert torch.allclose(out_root[-1], target_root, atol=1e-5)
    assert quat_angle(out_rot[-1], rot[-1]).max() < 1e-5
    pos, _ = forward_kinematics(out_rot, out_root, sk.offsets_tensor(), sk.parents)
    left = pos[:, sk.roles.left_foot[0]]
    # The planted left ankle does not move until the arrival frame, where it takes its target place.
    assert (left[1:-1] - left[0]).norm(dim=-1).max() < 0.05
    assert (left[-1] - left[0]).norm() == pytest.approx(4.0, abs=0.1)


def _ground_steps(root: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    ground = torch.cat([start[None], root])[:, ::2]
    return (ground[1:] - ground[:-1]).norm(dim=-1)


def test_a_capped_arrival_reaches_the_target_without_a_step_over_the_cap():
    walk = synthetic_walk(frames=60)
    gen_rot, gen_root = walk.rotations[1:41], walk.root_positions[1:41]
    start = walk.root_positions[0]
    speed = float(_ground_steps(gen_root, start).max())
    # A target 60 cm past where the motion ends: reachable at 1.5 times its speed in 40 frames, not in the last 10.
    ahead = gen_root[-1] - gen_root[-2]
    target_root = gen_root[-1] + ahead / ahead.norm() * 60.0
    cap = 1.5 * speed
    assert float((target_root - start)[::2].norm()) < 40 * cap
    _, loose = exact_arrival(gen_rot, gen_root, gen_rot[-1], target_root, walk.skeleton, window=10)
    print(f"walk {speed:.2f} cm/frame, cap {cap:.2f}; uncapped bend's top step "
          f"{float(_ground_steps(loose, start).max()):.2f}")
    assert float(_ground_steps(loose, start).max()) > cap  # the bend alone outruns it
    rot, root = exact_arrival(gen_rot, gen_root, gen_rot[-1], target_root, walk.skeleton, window=10, cap=cap,
                              start=start)
    steps = _ground_steps(root, start)
    print(f"capped bend's top step {float(steps.max()):.2f}")
    assert float(steps.max()) <= cap * 1.0001
    assert torch.allclose(root[-1], target_root, atol=1e-4)
    assert quat_angle(rot[-1], gen_rot[-1]).max() < 1e-5


def test_a_capped_arrival_out_of_reach_goes_straight_at_the_target_at_the_cap():
    walk = synthetic_walk(frames=60)
    gen_rot, gen_root = walk.rotations[1:21], walk.root_positions[1:21]
    start = walk.root_positions[0]
    cap = 1.2 * float(_ground_steps(gen_root, start).max())
    target_root = start + torch.tensor([0.0, 0.0, 1.0]) * (20 * cap + 50.0) + torch.tensor([0.0, gen_root[-1, 1], 0.0])
    _, root = exact_arrival(gen_rot, gen_root, gen_rot[-1], target_root, walk.skeleton, window=10, cap=cap,
                            start=start)
    assert float(_ground_steps(root, start).max()) <= cap * 1.0001
    miss = float((root[-1] - target_root)[::2].norm())
    assert miss >= 50.0 - 1e-3  # short by what the cap cannot cover, never dragged on

"""Stride warping: a foot the network plants stays put while steering carries the body, within the
cap; nothing moves without a shift, for a character standing, or on the arrival frame; the traced
frame output gives the eager frames."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.output.foot_lock import FootLock, FootLockConfig, FootLockStep
from model.inference.output.frame import world_pose
from model.inference.output.leg_chains import LegChains
from model.inference.output.pipeline import FrameSteps
from model.inference.output.settings import OutputConfig
from model.inference.output.stride_warp import StrideWarp, StrideWarpConfig, StrideWarpStep
from model.inference.traced_step import CompiledFrameOutput
from model.motion.features import CanonicalFrame
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import state_from_positions

FPS = 30.0
WHOLE = StrideWarpConfig(reach=1.0, slow_cm_s=0.0, full_cm_s=1.0)  # whole from the slightest speed


def _planted_walk(frames: int, speed_cm: float):
    """Frame 8 of the synthetic walk (left foot down) with its root moving along x at ``speed_cm`` a
    frame and the left ankle held where it starts by leg IK: the network's motion over a planted foot."""
    walk = synthetic_walk(frames=20)
    sk = walk.skeleton
    legs = LegChains(sk)
    rot = walk.rotations[8].expand(frames, -1, -1).clone()
    root = walk.root_positions[8].expand(frames, -1).clone()
    root[:, 0] += speed_cm * torch.arange(frames, dtype=torch.float32)
    pos, grot = legs.poses(rot[:1], root[:1])
    planted = pos[0, -1, 0]
    for t in range(frames):
        pos, grot = legs.poses(rot[t : t + 1], root[t : t + 1])
        targets = pos[:, -1].clone()
        targets[0, 0] = planted
        rot[t : t + 1] = legs.bend(rot[t : t + 1], pos, grot, targets, torch.tensor([[True, False]]))
    return sk, legs, rot, root


def _ankles(legs: LegChains, rot, root):
    return legs.poses(rot, root)[0][:, -1]


def _carried(settle: float):
    """The planted walk carried by steering half as far again as the network walks (1 cm a frame), warped:
    the left ankle's world positions carried and warped, and the shift the warp left."""
    speed, carried = 1.0, 0.5
    sk, legs, rot, root = _planted_walk(16, speed)
    assert (_ankles(legs, rot, root)[:, 0] - _ankles(legs, rot[:1], root[:1])[0, 0]).norm(dim=-1).max() < 0.05
    warp = StrideWarp(legs, FPS, StrideWarpConfig(reach=1.0, slow_cm_s=0.0, full_cm_s=1.0, settle=settle))
    shift, velocity = torch.tensor([[carried, 0.0, 0.0]]), torch.tensor([[speed, 0.0, 0.0]])
    memory = warp.start()
    moved_root = root + carried * torch.arange(16, dtype=torch.float32).unsqueeze(-1) * torch.tensor([1.0, 0.0, 0.0])
    shown, lefts = [], []
    for t in range(16):
        r, left, memory = warp.apply(rot[t : t + 1], moved_root[t : t + 1], torch.tensor([100]), velocity, shift,
                                     memory)
        shown.append(r[0])
        lefts.append(left)
    return _ankles(legs, rot, moved_root)[:, 0], _ankles(legs, torch.stack(shown), moved_root)[:, 0], torch.cat(lefts)


def test_a_planted_foot_stays_put_while_the_body_is_carried():
    carried_only, warped, left = _carried(settle=0.0)
    assert torch.allclose(left, torch.zeros_like(left), atol=1e-5)  # the warp took up the whole shift
    assert (carried_only[1:] - carried_only[:-1]).norm(dim=-1).min() > 0.45  # carried, the foot slides 0.5 a frame
    still = (warped[1:] - warped[:-1]).norm(dim=-1)
    assert still[:10].max() < 0.02  # warped, it stays where it was planted while the leg reaches (IK) ...
    assert 0.1 < still[-1] < 0.5  # ... then is pulled along, as far as the straight leg falls short


def test_the_settling_pull_moves_a_planted_foot_only_while_the_warp_sets_in():
    # Pulled toward the stateless offset, a foot planted when the warp starts slides by a share of the
    # offset the stateless form would have given it, less each frame, then stays put.
    _, warped, _ = _carried(settle=0.1)
    step = (warped[1:] - warped[:-1]).norm(dim=-1)
    assert (step[1:] <= step[:-1] + 1e-4).all()
    assert float(step[-1]) < 0.1 < float(step[0]) < 0.5


def test_the_cap_leaves_the_rest_of_the_shift_to_the_lock():
    warp = StrideWarp(LegChains(synthetic_walk(frames=4).skeleton), FPS, WHOLE)
    ratio = warp.ratio(torch.tensor([[3.0, 0.0, 4.0]]), torch.tensor([[1.0]]), torch.tensor([100]))
    assert torch.allclose(ratio.norm(dim=-1), torch.tensor([1.0]))  # |u| / |v| = 5, capped at the reach
    assert torch.allclose(ratio, torch.tensor([[0.6, 0.0, 0.8]]))  # the shift's direction kept


@pytest.mark.parametrize("case", ["no shift", "standing", "arrival"])
def test_nothing_moves_without_a_shift_standing_or_on_arrival(case: str):
    sk, legs, rot, root = _planted_walk(2, 1.0)
    warp = StrideWarp(legs, FPS, StrideWarpConfig(reach=1.0))  # the default gate: none under 15 cm/s
    velocity, shift, remaining = torch.tensor([[2.0, 0.0, 0.0]]), torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([20])
    if case == "no shift":
        shift = torch.zeros(1, 3)
    elif case == "standing":
        velocity = torch.tensor([[0.3, 0.0, 0.0]])  # 9 cm/s
    else:
        remaining = torch.tensor([0])
    r, left, memory = warp.apply(rot[:1], root[:1], remaining, velocity, shift, warp.start())
    assert torch.allclose(r, rot[:1], atol=1e-5)
    assert torch.allclose(left, shift)
    assert float(memory["warp_offset"].abs().max()) == 0.0


def test_config_is_validated():
    for bad in (lambda: StrideWarpConfig(reach=0.0), lambda: StrideWarpConfig(reach=5.0),
                lambda: StrideWarpConfig(reach=1.0, slow_cm_s=50.0), lambda: StrideWarpConfig(reach=1.0, settle=2.0)):
        with pytest.raises(ValueError):
            bad()
    with pytest.raises(ValueError):
        OutputConfig(stride_warp=-1.0)


def test_output_setting_round_trips_and_defaults_off():
    out = OutputConfig(smoothing=0.3, foot_lock=True, stride_warp=2.0)
    assert OutputConfig.from_dict(out.to_dict()) == out
    old = out.to_dict()
    del old["stride_warp"]  # a bundle saved before the setting existed
    assert OutputConfig.from_dict(old).stride_warp == 0.0
    assert out.with_overrides(stride_warp=0.0).stride_warp == 0.0
    assert out.with_overrides().stride_warp == 2.0


def test_traced_frame_output_gives_the_eager_frames():
    sk, legs, rot, root = _planted_walk(12, 4.0)
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.unsqueeze(0), quat_to_sixd(grot).unsqueeze(0), sk.roles.root)
    warp = StrideWarp(LegChains(sk), FPS, StrideWarpConfig(reach=1.0))
    output = FrameSteps(sk, {"stride_warp": StrideWarpStep(warp, lock_follows=False)})
    traced = CompiledFrameOutput(output, traced=True)
    eager_mem = {"prev_rot": rot[:1], "prev_root": root[:1], **warp.start()}
    traced_mem = dict(eager_mem)
    shift = torch.tensor([[1.5, 0.0]])
    warped = 0.0
    for t in range(1, 12):
        remaining = torch.tensor([11 - t])
        pose = states.index((slice(None), t))
        e_rot, e_root, eager_mem = output(pose, torch.zeros(1), torch.zeros(1, 3), remaining, eager_mem, shift=shift)
        t_rot, t_root, traced_mem = traced(pose, torch.zeros(1), torch.zeros(1, 3), remaining, traced_mem, shift=shift)
        assert torch.allclose(e_rot, t_rot, atol=1e-5) and torch.allclose(e_root, t_root)
        warped = max(warped, float(eager_mem["warp_offset"].norm(dim=-1).max()))
    assert warped > 0.5  # the warp moved the feet: the comparison is not of two untouched frames
    assert float(eager_mem["warp_offset"].abs().max()) == 0.0  # faded out by the arrival frame


def test_with_the_lock_the_legs_are_solved_once_for_what_warp_then_lock_give():
    # The frame output hands the warp's ankle moves to the lock, whose one IK reaches both; where the
    # legs reach, that is the warp's IK followed by the lock's.
    sk, legs, rot, root = _planted_walk(14, 3.0)  # slow enough for the leg to reach while held
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.unsqueeze(0), quat_to_sixd(grot).unsqueeze(0), sk.roles.root)
    warp = StrideWarp(LegChains(sk), FPS, StrideWarpConfig(reach=0.3))
    lock = FootLock(sk, FPS, FootLockConfig(contact_cm=3.0, lift_cm=5.0, release_cm=10.0))
    output = FrameSteps(sk, {"stride_warp": StrideWarpStep(warp, lock_follows=True), "foot_lock": FootLockStep(lock)})
    mem = {"prev_rot": rot[:1], "prev_root": root[:1], **warp.start(), **lock.start(rot[:2], root[:2]).memory()}
    warp_mem, lock_state = warp.start(), lock.start(rot[:2], root[:2])
    shift2 = torch.tensor([[0.8, 0.0]])
    shift3 = torch.tensor([[0.8, 0.0, 0.0]])
    moved = held = False
    for t in range(2, 14):
        remaining = torch.tensor([13 - t])
        pose = states.index((slice(None), t))
        one, _, mem = output(pose, torch.zeros(1), torch.zeros(1, 3), remaining, mem, eager=False, shift=shift2)
        velocity = pose.vel[:, sk.roles.root] - shift3
        local, world_root = world_pose(pose, CanonicalFrame(torch.zeros(1), torch.zeros(1, 3)), list(sk.parents),
                                       sk.roles.root)
        warped, left, warp_mem = warp.apply(local, world_root, remaining, velocity, shift3, warp_mem)
        two, lock_state = lock.apply(warped, world_root, remaining, lock_state, skip_idle=False, shift=left)
        assert torch.allclose(one, two, atol=1e-3)  # acos in the IK magnifies rounding near a straight leg
        assert torch.equal(mem["lock_locked"], lock_state.locked)
        held = held or bool(lock_state.locked.any())
        moved = moved or bool((one - local).abs().max() > 1e-3)
    assert moved and held  # the legs were bent and a foot held: the comparison is not of two untouched frames

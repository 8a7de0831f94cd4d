"""Foot locking: a planted foot is held while the body slides, lets go past its reach, and leaves
the arrival frame and feet in the air alone."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.inference.output.floor_contact import FloorContact, FloorStep
from model.inference.output.foot_lock import FootLock, FootLockConfig, FootLockState, FootLockStep
from model.inference.output.pipeline import FrameSteps
from model.inference.output.smoothing import Smoothing
from model.inference.traced_step import CompiledFrameOutput
from model.motion.kinematics import feet_kinematics, forward_kinematics
from model.motion.rotations import quat_to_sixd
from model.nets.pose_state import state_from_positions


def _sliding_pose(frames: int, speed_cm: float, still: int = 0):
    """Frame 8 of the synthetic walk (left foot down, right foot up) frozen, its root sliding along x
    after ``still`` frames."""
    walk = synthetic_walk(frames=20)
    rot = walk.rotations[8].expand(frames, -1, -1).clone()
    root = walk.root_positions[8].expand(frames, -1).clone()
    root[:, 0] += speed_cm * (torch.arange(frames, dtype=torch.float32) - still).clamp_min(0)
    return walk.skeleton, rot, root


def _run(lock: FootLock, rot, root, context: int, remaining_end: int = 100):
    state = lock.start(rot[:context], root[:context])
    out = []
    for t in range(context, rot.shape[0]):
        remaining = torch.tensor([remaining_end + rot.shape[0] - 1 - t])
        r, state = lock.apply(rot[t : t + 1], root[t : t + 1], remaining, state)
        out.append(r[0])
    return torch.stack(out), state


# The mechanics below are checked with these settings; the shipped defaults are tuned on data.
MECHANICS = FootLockConfig(contact_cm=3.0, lift_cm=5.0, release_cm=10.0, catch_up=0.5, rejoin_cm=1.0)


def test_planted_foot_is_held_then_released():
    sk, rot, root = _sliding_pose(50, speed_cm=0.5, still=9)  # a still context: the left foot is planted
    lock = FootLock(sk, 30.0, MECHANICS)
    out, _ = _run(lock, rot, root, context=10)
    gen = lock.ankles(rot[10:], root[10:])
    held = lock.ankles(out, root[10:])
    planted = held[0, 0]
    # The generated left ankle slides 0.5 cm a frame; the shown one stays put until the drift passes 10 cm.
    drift = (gen[:, 0] - planted)[:, [0, 2]].norm(dim=-1)
    while_held = drift < 9.9
    assert while_held.sum() >= 15
    assert (held[while_held, 0] - planted).norm(dim=-1).max() < 0.05
    # Released, it catches up with the generated foot, halving the gap each frame, then locks again
    # once within 1 cm (not before: re-locking mid catch-up would make it hop).
    gap = (held[:, 0] - gen[:, 0]).norm(dim=-1)
    r = int((~while_held).nonzero()[0])
    assert torch.allclose(gap[r : r + 4], gap[r - 1] * torch.tensor([0.5, 0.25, 0.125, 0.0625]), atol=0.02)
    assert gap[r + 2] > 1.0 > gap[r + 3]
    assert (held[r + 4 : r + 9, 0] - held[r + 4, 0]).norm(dim=-1).max() < 0.05
    # The right foot is 25 cm up: never locked, never moved.
    assert torch.allclose(held[:, 1], gen[:, 1], atol=1e-4)
    # Joints off the legs are untouched; the left foot keeps its world rotation.
    left = set(sk.legs[0])
    other = [j for j in range(sk.num_joints) if j not in left]
    assert torch.equal(out[:, other], rot[10:, other])
    _, g_out = forward_kinematics(out, root[10:], sk.offsets_tensor(), sk.parents)
    _, g_gen = forward_kinematics(rot[10:], root[10:], sk.offsets_tensor(), sk.parents)
    ankle = sk.legs[0][2]
    dots = (g_out[:, ankle] * g_gen[:, ankle]).sum(-1).abs()
    assert torch.allclose(dots, torch.ones_like(dots), atol=1e-5)


def test_fast_foot_does_not_lock_and_arrival_is_untouched():
    sk, rot, root = _sliding_pose(30, speed_cm=4.0)  # 120 cm/s: a foot moving that fast is not planted
    lock = FootLock(sk, 30.0, MECHANICS)
    out, state = _run(lock, rot, root, context=10)
    assert torch.equal(out, rot[10:]) and not state.locked.any()
    sk, rot, root = _sliding_pose(30, speed_cm=0.5)
    out, _ = _run(lock, rot, root, context=10, remaining_end=0)  # the last frame is the arrival frame
    assert torch.allclose(out[-1], rot[-1], atol=1e-6)
    assert not torch.allclose(out[5], rot[15], atol=1e-3)  # earlier frames were held


def test_traced_output_matches_eager_at_any_batch():
    # The engine's traced way out (world space, filter, foot lock) against the same code eager, on
    # three characters sliding at different speeds (held, released, never locked), one frame at a
    # time; the graph is traced on a first call at batch 1, then run at batch 3.
    speeds = (0.5, 1.5, 4.0)
    poses = [_sliding_pose(40, speed_cm=v, still=9) for v in speeds]
    sk = poses[0][0]
    rot = torch.stack([p[1] for p in poses], 1)  # [T, 3, J, 4]
    root = torch.stack([p[2] for p in poses], 1)
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.transpose(0, 1), quat_to_sixd(grot).transpose(0, 1), sk.roles.root)  # [3, T]
    yaw, origin = torch.zeros(3), torch.zeros(3, 3)
    lock = FootLock(sk, 30.0, MECHANICS)
    output = FrameSteps(sk, {"smoothing": Smoothing(0.2, 0.2), "foot_lock": FootLockStep(lock)})
    eager, traced = output, CompiledFrameOutput(output)

    def memory(rows: slice) -> dict[str, torch.Tensor]:
        starts = [lock.start(rot[:10, i], root[:10, i]) for i in range(3)[rows]]
        mem = {"prev_rot": rot[9, rows], "prev_root": root[9, rows], "speed_cap": torch.full((len(range(3)[rows]),), 4.0)}
        mem.update({k: torch.cat([s.memory()[k] for s in starts]) for k in FootLockState.MEMORY_KEYS})
        return mem

    traced(states.index((slice(0, 1), 10)), yaw[:1], origin[:1], torch.tensor([20]), memory(slice(0, 1)))
    assert traced._graph is not None

    def run(fn) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        mem, out = memory(slice(0, 3)), []
        for t in range(10, 40):
            r, _, mem = fn(states.index((slice(None), t)), yaw, origin, torch.full((3,), 39 - t), mem)
            out.append(r)
        return torch.stack(out), mem

    (e_out, e_mem), (t_out, t_mem) = run(eager), run(traced)
    assert torch.allclose(e_out, t_out, atol=1e-5)
    assert torch.equal(e_mem["lock_locked"], t_mem["lock_locked"])
    assert torch.allclose(e_mem["lock_anchor"], t_mem["lock_anchor"], atol=1e-4)
    # The lock did something to compare: the slow character's left ankle was held for a while.
    ankles = lock.ankles(e_out[:, 0], root[10:, 0])
    assert (ankles[1:12, 0] - ankles[0, 0]).norm(dim=-1).max() < 0.1


def test_legs_come_from_the_skeleton():
    sk, _, _ = _sliding_pose(2, speed_cm=0.0)
    assert [tuple(sk.names[j] for j in leg) for leg in sk.legs] == [("UpperLeg_L", "LowerLeg_L", "Foot_L"),
                                                                   ("UpperLeg_R", "LowerLeg_R", "Foot_R")]
    assert sk.chain_to(sk.index("Foot_L")) == tuple(sk.index(n) for n in ("Hips", "UpperLeg_L", "LowerLeg_L", "Foot_L"))


def test_config_is_validated():
    with pytest.raises(ValueError):
        FootLockConfig(contact_cm=6.0, lift_cm=5.0)
    with pytest.raises(ValueError):
        FootLockConfig(catch_up=0.0)


def test_a_foot_carried_by_steering_stays_locked():
    """The body slides 4 cm a frame: judged in the world the planted foot drifts away and is let go
    (10 cm), but when that slide is the engine's steering shift the network still holds the foot
    still, so the lock keeps it until it lifts."""
    sk, rot, root = _sliding_pose(30, speed_cm=4.0, still=9)
    lock = FootLock(sk, 30.0, MECHANICS)
    plain, _ = _run(lock, rot, root, context=10)
    state = lock.start(rot[:10], root[:10])
    shift = torch.tensor([[4.0, 0.0, 0.0]])
    carried = []
    for t in range(10, 30):
        r, state = lock.apply(rot[t : t + 1], root[t : t + 1], torch.tensor([100]), state, shift=shift)
        carried.append(r[0])
    planted = lock.ankles(rot[9:10], root[9:10])[0, 0]
    plain_left = (lock.ankles(plain, root[10:])[:, 0] - planted).norm(dim=-1)
    carried_left = (lock.ankles(torch.stack(carried), root[10:])[:, 0] - planted).norm(dim=-1)
    assert plain_left[-1] > 20.0  # released and dragged along
    assert (carried_left[:4] < 0.05).all()  # held exactly while the leg reaches (IK), past the 10 cm drift
    assert (carried_left < 0.5 * plain_left.clamp_min(1.0)).all()  # then pulled only as far as the leg falls short
    assert bool(state.locked[0, 0])


@pytest.mark.parametrize("shared", [True, False])
def test_floor_contact_and_the_lock_in_the_frame_output_give_what_each_gives_alone(shared: bool):
    # Given one kinematics object, the frame steps compute the legs' forward kinematics once for floor
    # contact and the lock (the lift moves every leg joint up alike); given two, each computes its own.
    # Run apart, each computes its own. A sinking, sliding body.
    sk, rot, root = _sliding_pose(30, speed_cm=1.0, still=9)
    root[10:, 1] -= torch.linspace(0.0, 8.0, 20)
    gpos, grot = forward_kinematics(rot, root, sk.offsets_tensor(), sk.parents)
    states = state_from_positions(gpos.unsqueeze(0), quat_to_sixd(grot).unsqueeze(0), sk.roles.root)
    legs = feet_kinematics(sk) if shared else None
    lock, floor = FootLock(sk, 30.0, MECHANICS, kinematics=legs), FloorContact(sk, kinematics=legs)
    assert (lock.kinematics is floor.kinematics) == shared
    output = FrameSteps(sk, {"floor_contact": FloorStep(floor), "foot_lock": FootLockStep(lock)})
    mem = {"prev_rot": rot[9:10], "prev_root": root[9:10], "floor": floor.floor(rot[:10], root[:10]),
           "lift_cap": torch.full((1,), float("inf")),  # only lifted, as FloorContact.lift
           **lock.start(rot[:10], root[:10]).memory()}
    state = lock.start(rot[:10], root[:10])
    ground = floor.floor(rot[:10], root[:10])
    lifted_any = held_any = False
    for t in range(10, 30):
        remaining = torch.tensor([29 - t])
        shared_rot, shared_root, mem = output(states.index((slice(None), t)), torch.zeros(1), torch.zeros(1, 3),
                                              remaining, mem, eager=False)
        lifted = floor.lift(rot[t:t + 1], root[t:t + 1], ground)
        alone_rot, state = lock.apply(rot[t:t + 1], lifted, remaining, state, skip_idle=False)
        lifted_any |= bool(lifted[0, 1] > root[t, 1] + 1.0)
        assert torch.allclose(shared_root, lifted, atol=1e-4)
        assert torch.allclose(shared_rot, alone_rot, atol=1e-3)  # acos in the IK magnifies rounding near a straight leg
        assert torch.equal(mem["lock_locked"], state.locked)
        held_any |= bool(state.locked.any())
    assert lifted_any and held_any  # both steps did something to compare

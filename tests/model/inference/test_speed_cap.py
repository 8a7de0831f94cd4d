"""The speed cap and the reach notice: no frame moves the root faster than its style's capture maximum, in whole
transitions and streams and after a retarget mid-stream; a target out of reach is said to be, and is not dragged to.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.character import Character, EncodedStyle
from model.inference.character_batch import CharacterBatch
from model.inference.engine import Engine
from model.inference.output.settings import OutputConfig
from model.inference.output.speed_cap import kept_in_reach, speed_capped
from model.inference.output.steering import SteeringConfig
from model.inference.overrides import Overrides
from model.inference.reach import Reach, reach_of
from model.motion.clip import Clip
from model.motion.gait_limits import GaitLimits, StyleGait
from model.nets.manifold import ManifoldConfig
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerConfig, SamplerState

J = 21
FPS = 30.0
SLOW, FAST = 60.0, 240.0  # cm/s: the two styles' capture maxima in these tests


def _state(root_xz: torch.Tensor) -> SamplerState:
    n = root_xz.shape[0]
    rel = torch.randn(n, J, 3, generator=torch.Generator().manual_seed(0))
    vel = torch.randn(n, J, 3, generator=torch.Generator().manual_seed(1))
    z = torch.zeros(n, 4)
    return SamplerState(z, z, PoseState(rel, vel, torch.randn(n, J, 6), root_xz), torch.zeros(n, 2, 2), z,
                        torch.zeros(n, J, 3), torch.zeros(n, J, 6), z, torch.tensor([10] * n), z)


def test_a_step_over_the_cap_is_pulled_back_to_it_and_the_others_are_left_alone() -> None:
    before = torch.zeros(3, 2)
    after = _state(torch.tensor([[30.0, 40.0], [1.0, 1.0], [-6.0, 8.0]]))  # steps of 50, 1.4 and 10 cm
    cap = torch.tensor([10.0, 10.0, math.inf])
    out, shift = speed_capped(before, after, None, cap)
    steps = (out.pose.root_xz - before).norm(dim=-1)
    assert steps.tolist() == pytest.approx([10.0, math.sqrt(2.0), 10.0])
    assert out.pose.root_xz[0].tolist() == pytest.approx([6.0, 8.0])  # back along its own step
    assert shift is not None and shift[0].tolist() == pytest.approx([-24.0, -32.0])
    assert shift[1:].abs().max() == 0
    # The whole body moves back: every joint's velocity by the same amount, relative positions unchanged.
    assert torch.allclose(out.pose.vel[0] - after.pose.vel[0], torch.tensor([-24.0, 0.0, -32.0]).expand(J, 3))
    assert torch.equal(out.pose.rel, after.pose.rel)


def test_a_root_falling_out_of_its_target_s_reach_is_moved_on_within_the_cap() -> None:
    before = torch.zeros(4, 2)
    after = _state(torch.full((4, 2), 0.0) + torch.tensor([0.0, 6.0]))  # each stepped 6 cm on, 10 frames left
    goal = torch.zeros(4, J, 3)
    # 102 cm to go (more than 10 frames at 10 cm), 84 (less), 119 (out of reach even from before), no cap.
    goal[:, 0, 2] = torch.tensor([108.0, 90.0, 125.0, 108.0])
    after = replace(after, target_pos=goal)
    cap = torch.tensor([10.0, 10.0, 10.0, math.inf])
    out, shift = kept_in_reach(before, after, None, cap, 0)
    # On to the nearest point still within reach (100 cm at 10 frames of 10 cm), or straight on at the cap.
    assert out.pose.root_xz[0].tolist() == pytest.approx([0.0, 8.0])
    assert out.pose.root_xz[2].tolist() == pytest.approx([0.0, 10.0])
    assert torch.equal(out.pose.root_xz[1], after.pose.root_xz[1]) and torch.equal(out.pose.root_xz[3],
                                                                                  after.pose.root_xz[3])
    assert shift is not None and shift[:, 1].tolist() == pytest.approx([2.0, 0.0, 4.0, 0.0])
    # The whole body moves on: every joint's velocity by the same amount.
    assert torch.allclose(out.pose.vel[0] - after.pose.vel[0], torch.tensor([0.0, 0.0, 2.0]).expand(J, 3))


def test_steering_s_shift_takes_the_pull_back() -> None:
    before = torch.zeros(1, 2)
    out, shift = speed_capped(before, _state(torch.tensor([[0.0, 20.0]])), torch.tensor([[0.0, 15.0]]),
                              torch.tensor([5.0]))
    assert out.pose.root_xz[0].tolist() == pytest.approx([0.0, 5.0])
    assert shift is not None and shift[0].tolist() == pytest.approx([0.0, 0.0])  # 15 carried, 15 taken back


def test_the_reach_notice() -> None:
    near = reach_of(300.0, 60, 200.0, FPS)  # 200 cm/s covers 400 cm in 2 s
    assert near.feasible and near.needed_frames == 45 and near.reachable_cm == pytest.approx(400.0)
    far = reach_of(930.0, 40, 200.0, FPS)
    assert not far.feasible and far.needed_frames == 140 and far.reachable_cm == pytest.approx(266.7, abs=0.1)
    assert far.to_dict() == {"feasible": False, "distance_cm": 930.0, "frames": 40, "needed_frames": 140,
                             "reachable_cm": 266.7, "max_speed_cm_s": 200.0}


def _bundle(limits: GaitLimits | None) -> Bundle:
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man, seed=3)
    bundle.gait_limits = limits
    # The shipped steps, steering carrying the body up to 15 cm a frame (450 cm/s: faster than either style here).
    bundle.output = OutputConfig(smoothing=0.3, foot_lock=True, steering=SteeringConfig(window=40, max_step_cm=15.0),
                                 floor=True, stride_warp=2.0)
    return bundle


LIMITS = GaitLimits({"slow": StyleGait(SLOW, SLOW * 0.9, {"walk": (80.0, 95.0)}, 3),
                     "fast": StyleGait(FAST, FAST * 0.9, {"walk": (80.0, 95.0)}, 3)}, "test", FPS)


def _far(walk: Clip, metres: float) -> Clip:
    target = walk.window(walk.num_frames - 1, walk.num_frames)
    root = target.root_positions.clone()
    root[:, 2] = walk.root_positions[9, 2] + metres * 100.0
    root[:, 0] = walk.root_positions[9, 0]
    return Clip(target.skeleton, target.rotations, root, target.fps)


def _root_speeds(roots: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
    path = torch.cat([start.unsqueeze(0), roots])[:, [0, 2]]
    return (path[1:] - path[:-1]).norm(dim=-1) * FPS


@pytest.mark.parametrize("gait", ["slow", "fast", ""])
def test_a_transition_never_moves_faster_than_its_style_and_says_it_falls_short(gait: str) -> None:
    walk = synthetic_walk(frames=120)
    engine = Engine(_bundle(LIMITS), compiled=False)
    style, _ = engine.encode_style(walk.window(0, 60))
    style.gait = gait  # "": a style registered from a clip, within the largest built-in maximum
    context = walk.window(0, 10)
    ch = engine.prepare(context, _far(walk, 6.0), 40, style, seed=1, exact_arrival=True)
    speed = {"slow": SLOW, "fast": FAST, "": FAST}[gait]
    assert ch.reach is not None and not ch.reach.feasible and ch.reach.max_speed_cm_s == speed
    assert ch.reach.needed_frames == math.ceil((ch.reach.distance_cm - 1.0) * FPS / speed)
    assert ch.arrival is not None and ch.aim.bent_to is None  # not dragged onto the target
    _, roots = engine.generate([ch])[0]
    speeds = _root_speeds(roots, context.root_positions[-1])
    assert float(speeds.max()) <= speed * 1.001
    uncapped = Engine(_bundle(None), compiled=False)
    free = uncapped.prepare(context, _far(walk, 6.0), 40, style, seed=1)
    assert free.reach is None
    _, free_roots = uncapped.generate([free])[0]
    assert float(_root_speeds(free_roots, context.root_positions[-1]).max()) > speed * 1.2  # the cap did the work


def test_a_stream_retargeted_far_mid_walk_stays_within_the_style_and_is_told() -> None:
    walk = synthetic_walk(frames=120)
    engine = Engine(_bundle(LIMITS), overrides=Overrides(), compiled=True)
    style, _ = engine.encode_style(walk.window(0, 60))
    style.gait = "slow"
    context = walk.window(0, 10)
    near = walk.window(14, 15)  # 20 cm on: in reach
    ch = engine.prepare(context, near, 30, style, seed=2)
    other = engine.prepare(context, near, 30, style, seed=3)  # a second character in the batch, not retargeted
    assert ch.reach is not None and ch.reach.feasible
    batch = CharacterBatch(engine)
    batch.add(ch)
    batch.add(other)
    roots = []
    while len(batch):
        if ch.seq == 10:
            reach = engine.retarget(ch, batch, target=_far(walk, 5.0), frames=30)
            assert reach is ch.reach and reach is not None and not reach.feasible and reach.frames == 30
        out = batch.step()
        roots.append(out.root_positions[out.characters.index(ch)])
        batch.drop_finished()
    speeds = _root_speeds(torch.stack(roots), context.root_positions[-1])
    assert len(speeds) == 40 and float(speeds.max()) <= SLOW * 1.001


def test_a_floating_body_is_lowered_to_its_style_s_lift_and_a_sinking_one_still_raised() -> None:
    from model.inference.output.floor_contact import FloorContact

    walk = synthetic_walk(frames=20)
    contact = FloorContact(synthetic_skeleton())
    rot, root = walk.rotations[:10], walk.root_positions[:10]
    floor = contact.floor(rot, root)
    lowest = float(contact.foot_heights(rot[-1:], root[-1:]).min())
    for rise, cap, moved in ((30.0, 12.0, 12.0 - (lowest + 30.0 - float(floor))), (30.0, math.inf, 0.0),
                             (5.0, 12.0, 0.0), (-8.0, 12.0, 8.0 - contact.tolerance - (lowest - float(floor)))):
        up = root[-1:].clone()
        up[:, 1] += rise
        change = contact.lift_of(contact.kinematics(rot[-1:], up)[0], floor, torch.tensor([cap]))
        assert change[0, 1].item() == pytest.approx(moved, abs=1e-4), (rise, cap)
        assert change[0, ::2].abs().max() == 0


def _switched_at(engine: Engine, ch: Character, style: EncodedStyle, seq: int) -> tuple[Reach | None, torch.Tensor]:
    """Run ``ch`` to its end in a batch, its style switched to ``style`` before frame ``seq``: the notice that
    switch returned, and its roots."""
    batch = CharacterBatch(engine)
    batch.add(ch)
    reach, roots = None, []
    while len(batch):
        if ch.seq == seq:
            reach = engine.set_style(ch, style, batch)
        out = batch.step()
        roots.append(out.root_positions[0])
        batch.drop_finished()
    return reach, torch.stack(roots)


def test_a_style_switch_works_the_reach_out_again_at_the_new_style_s_speed() -> None:
    walk = synthetic_walk(frames=120)
    engine = Engine(_bundle(LIMITS), compiled=False)
    fast, _ = engine.encode_style(walk.window(0, 60))
    fast.gait = "fast"
    slow = replace(fast, gait="slow")
    context, target = walk.window(0, 10), _far(walk, 1.5)
    goal = target.root_positions[-1, [0, 2]]
    # In reach at the fast style's 240 cm/s (150 cm in 40 frames); switched to the slow one (60 cm/s) with 30 frames
    # left it is not: the switch says so, and exact arrival no longer drags the walk onto the target.
    ch = engine.prepare(context, target, 40, fast, seed=1, exact_arrival=True)
    assert ch.reach is not None and ch.reach.feasible and ch.aim.bent_to is not None
    reach, roots = _switched_at(engine, ch, slow, 10)
    assert reach is ch.reach and reach is not None and not reach.feasible
    assert reach.max_speed_cm_s == SLOW and reach.frames == 30 and reach.distance_cm > reach.reachable_cm + 1.0
    assert ch.arrival is not None and ch.aim.bent_to is None
    speeds = _root_speeds(roots, context.root_positions[-1])
    print(f"fast -> slow: {reach.to_dict()}, top speed after {float(speeds[10:].max()):.1f} cm/s, ends "
          f"{float((roots[-1, [0, 2]] - goal).norm()):.1f} cm short")
    assert float(speeds[10:].max()) <= SLOW * 1.001  # before the fix exact arrival dragged it at 480 cm/s
    assert float((roots[-1, [0, 2]] - goal).norm()) > 50.0
    # Out of reach at the slow style (80 cm in 40 frames), switched to the fast one it is in reach: it arrives.
    ch = engine.prepare(context, target, 40, slow, seed=1, exact_arrival=True)
    assert ch.reach is not None and not ch.reach.feasible and ch.aim.bent_to is None
    reach, roots = _switched_at(engine, ch, fast, 10)
    assert reach is ch.reach and reach is not None and reach.feasible and reach.max_speed_cm_s == FAST
    assert ch.aim.bent_to is not None
    assert float((roots[-1, [0, 2]] - goal).norm()) < 1.0

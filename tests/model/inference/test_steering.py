"""Root steering: the shift's math, the facing and height it finishes, the state it writes, its settings, and an
engine that arrives."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.character_batch import CharacterBatch
from model.inference.engine import Engine
from model.inference.output.arrival import arrival_weight
from model.inference.output.settings import OutputConfig
from model.inference.output.steering import (
    SteeringConfig,
    finishing_rise,
    finishing_turn,
    steer,
    steering_shift,
    turned_and_raised,
)
from model.inference.overrides import Overrides
from model.inference.traced_step import CompiledStep
from model.motion.clip import Clip
from model.motion.features import FacingChains, facing_yaw
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_mul, quat_normalize, quat_to_sixd, yaw_quat
from model.nets.manifold import ManifoldConfig
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerConfig, SamplerState

J = 21
Tensor = torch.Tensor


def _small_bundle(seed: int) -> Bundle:
    """An untrained bundle of the synthetic skeleton, small enough to run in a test."""
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Bundle.create(synthetic_skeleton(), cfg, man, seed=seed)


def _state(root_xz, vel_xz, goal_xz, tta) -> SamplerState:
    n = len(tta)
    vel = torch.zeros(n, J, 3)
    vel[:, :, 0], vel[:, :, 2] = vel_xz[:, :1], vel_xz[:, 1:]
    rel = torch.randn(n, J, 3, generator=torch.Generator().manual_seed(0))
    target = torch.zeros(n, J, 3)
    target[:, 0, 0], target[:, 0, 2] = goal_xz[:, 0], goal_xz[:, 1]
    pose = PoseState(rel, vel, torch.randn(n, J, 6), root_xz)
    z = torch.zeros(n, 4)
    return SamplerState(z, z, pose, torch.zeros(n, 2, 2), z, target, torch.zeros(n, J, 6), z,
                        torch.tensor(tta), z)


xz = st.tuples(st.floats(-300, 300), st.floats(-300, 300))


@settings(max_examples=60, deadline=None)
@given(p=xz, v=xz, g=xz, r=st.integers(0, 80), window=st.integers(1, 60))
def test_the_shift_is_capped_zero_outside_the_window_and_lands_the_last_frame(p, v, g, r, window):
    config = SteeringConfig(window=window, max_step_cm=10.0)
    t = lambda a: torch.tensor([a], dtype=torch.float32)  # noqa: E731
    state = _state(t(p), t(v) / 10, t(g), [r])
    shift = steering_shift(state, 0, config)[0]
    assert shift.norm() <= 10.0 + 1e-4
    if r >= window:
        assert torch.all(shift == 0)
    if r == 0:  # the arrival frame: the whole miss, up to the cap
        miss = t(g)[0] - t(p)[0]
        expected = miss * min(1.0, 10.0 / max(float(miss.norm()), 1e-9))
        assert torch.allclose(shift, expected, atol=1e-3)


def test_no_shift_when_the_character_is_on_course():
    # 10 frames left at 3 cm a frame along x from x = 0: the goal at x = 30 is where it will be.
    state = _state(torch.zeros(1, 2), torch.tensor([[3.0, 0.0]]), torch.tensor([[30.0, 0.0]]), [10])
    assert torch.allclose(steering_shift(state, 0, SteeringConfig(window=40)), torch.zeros(1, 2), atol=1e-6)
    # Half the speed expected to be kept (momentum 0.5): it is predicted 15 cm short and pushed on.
    assert steering_shift(state, 0, SteeringConfig(window=40, momentum=0.5))[0, 0] > 0


def test_steer_moves_the_whole_body_and_its_velocity():
    state = _state(torch.zeros(2, 2), torch.zeros(2, 2), torch.tensor([[50.0, 0.0], [0.0, -20.0]]), [0, 5])
    moved, shift = steer(state, 0, SteeringConfig(window=10))
    before, after = state.pose.positions(), moved.pose.positions()
    ground = torch.stack([shift[:, 0], torch.zeros(2), shift[:, 1]], -1).unsqueeze(1)
    assert torch.allclose(after - before, ground.expand_as(before))
    assert torch.allclose(moved.pose.vel - state.pose.vel, ground.expand_as(before))
    assert torch.equal(moved.pose.rel, state.pose.rel) and torch.equal(moved.pose.rot, state.pose.rot)
    assert torch.allclose(shift[0], torch.tensor([10.0, 0.0]))  # the arrival frame, capped at 10 cm


def test_weight_rises_from_zero_to_one():
    w = arrival_weight(torch.arange(45, -1, -1), 40)  # the smoothstep steering shares with exact arrival
    assert torch.all(w[:6] == 0) and w[-1] == 1 and torch.all(w[1:] >= w[:-1])


def test_settings_are_checked_and_saved_with_the_output_settings():
    for bad in ({"window": -1}, {"momentum": 1.5}, {"max_step_cm": 0.0}):
        with pytest.raises(ValueError):
            SteeringConfig(**bad)
    with pytest.raises(ValueError, match="unknown steering settings: speed"):
        SteeringConfig.from_dict({"speed": 1})
    out = OutputConfig(0.3, True).with_overrides(steering=25)
    assert out.steering == SteeringConfig(window=25)
    assert OutputConfig.from_dict(out.to_dict()) == out
    assert OutputConfig.from_dict({"smoothing": 0.3}).steering.on is False  # bundles saved before steering
    assert out.with_overrides(steering=0).steering.on is False
    for bad in ({"turn_window": -2}, {"height_window": -1}, {"max_turn_deg": 0.0}, {"max_rise_cm": -1.0}):
        with pytest.raises(ValueError):
            SteeringConfig(**bad)
    # Saved before the facing and height parts existed: they load off.
    old = SteeringConfig.from_dict({"window": 40, "momentum": 1.0, "max_step_cm": 10.0})
    assert old.turn_window == 0 and old.height_window == 0
    full = SteeringConfig(window=40, turn_window=10, height_window=10)
    assert full.with_window(25) == SteeringConfig(window=25, turn_window=10, height_window=10)
    assert full.with_window(0).on is False  # 0: the network alone, every part off
    assert SteeringConfig(turn_window=5).on and SteeringConfig(height_window=5).on


def _far_arrival(engine: Engine, walk: Clip, frames: int) -> float:
    style, _ = engine.encode_style(walk.window(30, 150))
    target = walk.window(20, 21)  # about 40 cm ahead of the context, then 60 cm to the side
    far = Clip(walk.skeleton, target.rotations, target.root_positions + torch.tensor([60.0, 0.0, 0.0]), walk.fps)
    ch = engine.prepare(walk.window(0, 10), far, frames, style, deterministic=True)
    _, roots = engine.generate([ch])[0]
    return float((roots[-1] - far.root_positions[-1])[[0, 2]].norm())


def test_a_random_network_is_steered_onto_a_far_target():
    bundle = _small_bundle(1)
    walk = synthetic_walk(frames=160)
    off = _far_arrival(Engine(bundle, overrides=Overrides(steering=0)), walk, 30)
    on = _far_arrival(Engine(bundle, overrides=Overrides(steering=30)), walk, 30)
    assert off > 50.0
    assert on < 1.0


def test_the_default_model_steers_by_its_own_settings():
    bundle = Bundle.load(DEFAULT_BUNDLE)
    steering = bundle.output.steering
    assert (steering.window, steering.turn_window, steering.height_window) == (40, 5, 5)
    walk = synthetic_walk(frames=160)
    off = _far_arrival(Engine(bundle, threads=1, overrides=Overrides(steering=0)), walk, 40)
    on = _far_arrival(Engine(bundle, threads=1), walk, 40)
    assert on < 0.25 * off


def _skeleton_rotations(seed: int, n: int = 6):
    sk = synthetic_skeleton()
    g = torch.Generator().manual_seed(seed)
    local = quat_normalize(torch.randn(n, sk.num_joints, 4, generator=g))
    pos, glob = forward_kinematics(local, torch.zeros(n, 3), sk.offsets_tensor(), sk.parents)
    return sk, pos, quat_to_sixd(glob)


def _posed_state(seed: int, tta: list[int]) -> tuple[SamplerState, FacingChains]:
    sk, pos, rot6 = _skeleton_rotations(seed, 2 * len(tta))
    n = len(tta)
    g = torch.Generator().manual_seed(seed + 1)
    here, there = pos[:n], pos[n:]
    rel = here.clone()
    rel[..., 0] -= here[:, :1, 0]
    rel[..., 2] -= here[:, :1, 2]
    rel[..., 1] += 90.0
    pose = PoseState(rel, torch.randn(n, sk.num_joints, 3, generator=g), rot6[:n], here[:, 0, ::2])
    target = there + torch.tensor([0.0, 95.0, 0.0])
    z = torch.zeros(n, 4)
    state = SamplerState(z, z, pose, torch.zeros(n, 2, 2), z, target, rot6[n:], z, torch.tensor(tta), z)
    return state, FacingChains.of(sk)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), r=st.integers(0, 30), window=st.integers(1, 20))
def test_the_turn_and_rise_are_capped_zero_outside_their_window_and_finish_on_arrival(seed, r, window):
    state, facing = _posed_state(seed, [r])
    config = SteeringConfig(turn_window=window, max_turn_deg=180.0, height_window=window, max_rise_cm=1000.0)
    turn, rise = finishing_turn(state, config, facing), finishing_rise(state, 0, config)
    assert float(turn.abs().max()) <= torch.pi + 1e-5
    capped = SteeringConfig(turn_window=window, max_turn_deg=3.0, height_window=window, max_rise_cm=0.5)
    assert float(finishing_turn(state, capped, facing).abs().max()) <= 3.0 * torch.pi / 180 + 1e-6
    assert float(finishing_rise(state, 0, capped).abs().max()) <= 0.5 + 1e-6
    if r >= window:
        assert torch.all(turn == 0) and torch.all(rise == 0)
    if r == 0:  # the arrival frame: the whole facing and height miss taken up
        done = turned_and_raised(state, turn, rise)
        miss = facing.yaw(done.target_rot) - facing.yaw(done.pose.rot)
        assert torch.allclose(torch.atan2(torch.sin(miss), torch.cos(miss)), torch.zeros(1), atol=1e-4)
        assert torch.allclose(done.pose.rel[:, 0, 1], done.target_pos[:, 0, 1], atol=1e-4)


def test_turning_keeps_the_body_rigid_about_its_root():
    state, facing = _posed_state(3, [4, 9])
    turn, rise = torch.tensor([0.4, -1.1]), torch.tensor([2.0, -1.5])
    done = turned_and_raised(state, turn, rise)
    before, after = state.pose.rel, done.pose.rel
    assert torch.allclose(torch.cdist(before, before), torch.cdist(after, after), atol=1e-3)  # a rigid motion
    assert torch.allclose(after[:, 0, ::2], before[:, 0, ::2], atol=1e-5)  # about the root's vertical
    assert torch.allclose(after[..., 1] - before[..., 1], rise.unsqueeze(-1).expand_as(after[..., 1]), atol=1e-4)
    gained = facing.yaw(done.pose.rot) - facing.yaw(state.pose.rot)
    assert torch.allclose(torch.atan2(torch.sin(gained), torch.cos(gained)), turn, atol=1e-4)
    assert torch.equal(done.pose.root_xz, state.pose.root_xz)


def test_steer_with_only_the_finishing_parts_gives_no_ground_shift():
    state, facing = _posed_state(5, [0, 2])
    moved, shift = steer(state, 0, SteeringConfig(turn_window=5, height_window=5), facing)
    assert torch.equal(shift, torch.zeros(2, 2)) and torch.equal(moved.pose.root_xz, state.pose.root_xz)
    assert not torch.equal(moved.pose.rot, state.pose.rot)
    with pytest.raises(ValueError, match="facing chains"):
        steer(state, 0, SteeringConfig(turn_window=5))


def test_a_step_that_turns_the_facing_needs_the_skeleton():
    bundle = _small_bundle(1)
    with pytest.raises(ValueError, match="facing chains"):
        CompiledStep(bundle.sampler, 0, SteeringConfig(turn_window=10))


def _turned_arrival(engine: Engine, walk: Clip, frames: int) -> tuple[float, float]:
    """Facing (degrees) and root height (cm) missed on arrival at a target turned 90 degrees and lowered 6 cm."""
    style, _ = engine.encode_style(walk.window(30, 150))
    target = walk.window(20, 21)
    turn = yaw_quat(torch.tensor(torch.pi / 2))  # 90 degrees about +Y
    rotations = target.rotations.clone()
    rotations[:, 0] = quat_mul(turn, rotations[:, 0])
    roots = target.root_positions - torch.tensor([0.0, 6.0, 0.0])
    turned = Clip(walk.skeleton, rotations, roots, walk.fps)
    ch = engine.prepare(walk.window(0, 10), turned, frames, style, deterministic=True)
    rot, root = engine.generate([ch])[0]
    sk = walk.skeleton
    pos, _ = forward_kinematics(rot[-1:], root[-1:], sk.offsets_tensor(), sk.parents)
    want, _ = forward_kinematics(turned.rotations, turned.root_positions, sk.offsets_tensor(), sk.parents)
    miss = facing_yaw(pos, sk) - facing_yaw(want, sk)
    angle = float(torch.atan2(torch.sin(miss), torch.cos(miss)).abs()) * 180 / torch.pi
    return angle, float((root[-1, 1] - turned.root_positions[-1, 1]).abs())


def test_a_random_network_arrives_facing_the_target_at_its_height():
    bundle = _small_bundle(3)  # untrained: it drifts to face about +35°
    walk = synthetic_walk(frames=160)
    finish = OutputConfig(0.0, False, steering=SteeringConfig(window=30, turn_window=10, max_turn_deg=45.0,
                                                              height_window=10, max_rise_cm=5.0))
    bundle.output = finish
    plain = Engine(bundle, threads=1, overrides=Overrides(steering=0))
    for compiled in (True, False):
        angle, height = _turned_arrival(Engine(bundle, threads=1, compiled=compiled), walk, 30)
        assert angle < 1.0 and height < 0.5, (compiled, angle, height)
    angle_off, _ = _turned_arrival(plain, walk, 30)
    assert angle_off > 20.0


def test_frames_before_the_finishing_windows_skip_their_parts_and_change_nothing():
    bundle = _small_bundle(3)
    bundle.output = OutputConfig(0.0, False, steering=SteeringConfig(window=20, turn_window=4, height_window=3))
    walk = synthetic_walk(frames=160)
    frames = []
    for shortcut in (True, False):
        engine = Engine(bundle, threads=1)
        if not shortcut:  # every frame through the full steering
            for weights in engine.weight_sets.values():
                weights.step_fn._cruise = None
        style, _ = engine.encode_style(walk.window(30, 150))
        ch = engine.prepare(walk.window(0, 10), walk.window(20, 21), 16, style, deterministic=True)
        frames.append(engine.generate([ch])[0])
        keys = set(engine.weights().step_fn._graphs)
        assert keys == ({"", "cruise"} if shortcut else {""})
    (rot_a, root_a), (rot_b, root_b) = frames
    assert torch.allclose(rot_a, rot_b, atol=1e-6) and torch.allclose(root_a, root_b, atol=1e-5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), r=st.integers(0, 30))
def test_rows_retargeted_mid_stream_take_the_retarget_window_and_cap_and_the_others_do_not(seed, r):
    state, facing = _posed_state(seed, [r, r])
    config = SteeringConfig(turn_window=5, max_turn_deg=4.0, retarget_turn_window=20, retarget_max_turn_deg=10.0)
    late = torch.tensor([False, True])
    turn = finishing_turn(state, config, facing, late)
    usual = finishing_turn(state, SteeringConfig(turn_window=5, max_turn_deg=4.0), facing)
    retarget = finishing_turn(state, SteeringConfig(turn_window=20, max_turn_deg=10.0), facing)
    assert torch.equal(turn[0], usual[0]) and torch.allclose(turn[1], retarget[1], atol=1e-7)
    assert float(turn[1].abs()) <= 10.0 * torch.pi / 180 + 1e-6
    if r >= 20:
        assert torch.all(turn == 0)
    assert torch.equal(finishing_turn(state, config, facing), usual)  # no rows flagged: the usual settings


def test_a_retarget_window_alone_turns_only_the_flagged_rows():
    state, facing = _posed_state(7, [3, 3])
    config = SteeringConfig(retarget_turn_window=10, retarget_max_turn_deg=30.0)
    assert config.on and config.turns
    turn = finishing_turn(state, config, facing, torch.tensor([True, False]))
    assert float(turn[0].abs()) > 0 and float(turn[1]) == 0.0
    assert not SteeringConfig(window=40, retarget_turn_window=10).with_window(0).on
    with pytest.raises(ValueError, match="retarget turn window"):
        SteeringConfig(retarget_turn_window=-1)
    with pytest.raises(ValueError, match="retarget_max_turn_deg"):
        SteeringConfig(retarget_max_turn_deg=0.0)


USUAL = SteeringConfig(window=20, turn_window=3, max_turn_deg=4.0, height_window=3)
LATE = SteeringConfig(**{**USUAL.to_dict(), "retarget_turn_window": 8, "retarget_max_turn_deg": 30.0})


def _turned_target(walk: Clip) -> Clip:
    """The walk's frame 20, turned 90 degrees about its vertical and moved 80 cm along x."""
    target = walk.window(20, 21)
    rotations = target.rotations.clone()
    rotations[:, 0] = quat_mul(yaw_quat(torch.tensor(torch.pi / 2)), rotations[:, 0])
    return Clip(walk.skeleton, rotations, target.root_positions + torch.tensor([80.0, 0.0, 0.0]), walk.fps)


def _retargeted_streams(bundle: Bundle, compiled: bool) -> tuple[list[list[tuple[Tensor, Tensor]]], set[str]]:
    """Two characters in one batch walking to one target; the first is retargeted to a target turned 90
    degrees and moved at frame 6 of 16. Each character's frames, and the traced graphs that ran."""
    engine = Engine(bundle, threads=1, compiled=compiled)
    walk = synthetic_walk(frames=160)
    style, _ = engine.encode_style(walk.window(30, 150))
    target = walk.window(20, 21)
    turned = _turned_target(walk)
    batch = CharacterBatch(engine)
    chars = [engine.prepare(walk.window(0, 10), target, 16, style, deterministic=True) for _ in range(2)]
    for ch in chars:
        batch.add(ch)
    frames: dict[str, list[tuple[Tensor, Tensor]]] = {ch.id: [] for ch in chars}
    for frame in range(16):
        if frame == 6:
            engine.retarget(chars[0], batch, target=turned)
        out = batch.step()
        for i, ch in enumerate(out.characters):
            frames[ch.id].append((out.rotations[i], out.root_positions[i]))
        batch.drop_finished()
    assert chars[0].retargeted and not chars[1].retargeted
    return [frames[ch.id] for ch in chars], set(engine.weights().step_fn._graphs)


def test_a_retarget_finishes_its_facing_harder_and_leaves_the_others_as_they_were():
    bundle = _small_bundle(3)
    results = {}
    for name, steering in (("usual", USUAL), ("late", LATE)):
        bundle.output = OutputConfig(0.0, False, steering=steering)
        for compiled in (True, False):
            results[name, compiled], graphs = _retargeted_streams(bundle, compiled)
            if compiled:
                assert ("late" in graphs) == (name == "late")
    for compiled in (True, False):
        usual_frames, late_frames = results["usual", compiled], results["late", compiled]
        for a, b in zip(usual_frames[1], late_frames[1]):  # the character never retargeted: the same frames
            assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
        for a, b in zip(usual_frames[0][:6], late_frames[0][:6]):  # the retargeted one, before its retarget
            assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
        assert not torch.allclose(usual_frames[0][-1][0], late_frames[0][-1][0], atol=1e-3)  # turned harder
    for name in ("usual", "late"):  # traced and eager agree
        for a, b in zip(results[name, True][0], results[name, False][0]):
            assert torch.allclose(a[0], b[0], atol=1e-4) and torch.allclose(a[1], b[1], atol=1e-3)


def test_a_start_marked_retargeted_finishes_its_facing_as_a_retargeted_character_does():
    """A stream resumed on another server after a retarget starts with ``retargeted``: it takes the retarget
    window (where the bundle has one) from its first frame; without one the flag changes nothing."""
    bundle = _small_bundle(3)
    walk = synthetic_walk(frames=160)
    turned = _turned_target(walk)
    last = {}
    for name, steering in (("usual", USUAL), ("late", LATE)):
        bundle.output = OutputConfig(0.0, False, steering=steering)
        engine = Engine(bundle, threads=1, compiled=False)
        style, _ = engine.encode_style(walk.window(30, 150))
        for flag in (False, True):
            ch = engine.prepare(walk.window(0, 10), turned, 10, style, deterministic=True, retargeted=flag)
            assert ch.retargeted is flag
            batch = CharacterBatch(engine)
            batch.add(ch)
            for _ in range(10):
                out = batch.step()
            last[name, flag] = out.rotations[0]
    assert torch.equal(last["usual", False], last["usual", True])
    assert torch.equal(last["usual", False], last["late", False])
    assert not torch.allclose(last["late", False], last["late", True], atol=1e-3)

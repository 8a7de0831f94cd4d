"""Root steering: the shift's math, the state it writes, its settings, and an engine that arrives."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.arrival import arrival_weight
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import Engine
from model.inference.output_settings import OutputConfig
from model.inference.steering import SteeringConfig, steer, steering_shift
from model.motion.clip import Clip
from model.nets.manifold import ManifoldConfig
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerConfig, SamplerState

J = 21


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


def _far_arrival(engine: Engine, walk: Clip, frames: int) -> float:
    style, _ = engine.encode_style(walk.window(30, 150))
    target = walk.window(20, 21)  # about 40 cm ahead of the context, then 60 cm to the side
    far = Clip(walk.skeleton, target.rotations, target.root_positions + torch.tensor([60.0, 0.0, 0.0]), walk.fps)
    ch = engine.prepare(walk.window(0, 10), far, frames, style, deterministic=True)
    _, roots = engine.generate([ch])[0]
    return float((roots[-1] - far.root_positions[-1])[[0, 2]].norm())


def test_a_random_network_is_steered_onto_a_far_target():
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man, seed=1)
    walk = synthetic_walk(frames=160)
    off = _far_arrival(Engine(bundle, steering=0), walk, 30)
    on = _far_arrival(Engine(bundle, steering=30), walk, 30)
    assert off > 50.0
    assert on < 1.0


def test_the_default_model_steers_by_its_own_settings():
    bundle = Bundle.load(DEFAULT_BUNDLE)
    assert bundle.output.steering.window == 40
    walk = synthetic_walk(frames=160)
    off = _far_arrival(Engine(bundle, steering=0, threads=1), walk, 40)
    on = _far_arrival(Engine(bundle, threads=1), walk, 40)
    assert on < 0.25 * off

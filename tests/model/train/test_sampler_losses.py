"""The sampler stage: its motion losses, how rollouts are grouped, and compiled training steps."""

from __future__ import annotations

from typing import cast

import pytest
import torch

from model.train.sampler_losses import acceleration_profile, planted_foot_speed


def test_acceleration_profile_is_zero_at_constant_velocity_and_measures_each_joint():
    vel = torch.zeros(2, 6, 3, 3)
    vel[..., 0] = 1.5  # every joint moves steadily
    assert torch.allclose(acceleration_profile(vel), torch.zeros(2, 3), atol=1e-3)
    t = torch.arange(6, dtype=torch.float32)
    vel[:, :, 1, 2] = 2.0 * t  # joint 1 speeds up by 2 cm/frame every frame
    prof = acceleration_profile(vel)
    assert torch.allclose(prof[:, 1], torch.full((2,), 2.0), atol=1e-3)
    assert torch.allclose(prof[:, 0], torch.zeros(2), atol=1e-3)


def _feet(heights: list[float], dx: float, dy: float = 0.0, frames: int = 5) -> torch.Tensor:
    pos = torch.zeros(1, frames, 3, 3)
    t = torch.arange(frames, dtype=torch.float32)
    for j, h in enumerate(heights):
        pos[0, :, j, 0] = dx * t
        pos[0, :, j, 1] = h + dy * t
    return pos


def test_planted_foot_speed_counts_horizontal_sliding_on_the_ground_only():
    ground = torch.tensor([4.0, 12.0])
    feet = [1, 2]
    sliding = planted_foot_speed(_feet([0.0, 4.0, 12.0], dx=1.0), feet, ground)
    assert torch.isclose(sliding, torch.tensor(1.0), atol=1e-3)
    assert planted_foot_speed(_feet([0.0, 10.0, 20.0], dx=1.0), feet, ground) == 0  # both feet in the air
    lifting = planted_foot_speed(_feet([0.0, 4.0, 12.0], dx=0.0, dy=0.2), feet, ground)
    assert lifting < 1e-3  # rising straight up is not sliding


def test_planted_foot_speed_slows_feet_rather_than_lifting_them():
    pos = _feet([0.0, 4.5, 12.5], dx=1.0).requires_grad_(True)
    planted_foot_speed(pos, [1, 2], torch.tensor([4.0, 12.0])).backward()
    assert pos.grad is not None
    assert pos.grad[..., 1].abs().max() == 0  # no gradient on height
    assert pos.grad[..., 0].abs().max() > 0


def test_velocity_spectrum_puts_jitter_at_the_top_and_ignores_timing():
    from model.train.sampler_losses import velocity_spectrum

    frames = 20
    t = torch.arange(frames, dtype=torch.float32)
    steady = torch.zeros(1, frames, 1, 3)
    steady[..., 0] = 2.0
    jitter = steady.clone()
    jitter[0, :, 0, 1] = torch.where(t % 2 == 0, 1.0, -1.0)  # a frame-to-frame back-and-forth
    floor = torch.log(torch.tensor(0.1))
    assert torch.allclose(velocity_spectrum(steady), torch.full((1, frames // 2 + 1, 1), float(floor)))
    spec = velocity_spectrum(jitter)[0, :, 0]
    assert spec.argmax() == frames // 2 and spec[: frames // 2].max() <= floor + 1e-4
    # The same rhythm a few frames later has the same spectrum: timing is not asked for.
    wave = torch.zeros(1, frames, 1, 3)
    wave[0, :, 0, 0] = torch.sin(2 * torch.pi * 4 * t / frames)
    later = torch.roll(wave, 3, dims=1)
    assert torch.allclose(velocity_spectrum(wave), velocity_spectrum(later), atol=1e-4)


def test_a_critic_that_reads_rotations_is_refused_when_the_config_is_made():
    import pytest

    from model.train.sampler_config import SamplerStageConfig

    # A name or a list where the field is a tuple, on purpose: what a JSON config (or one written before
    # critics became a list) holds, which __post_init__ turns into a tuple; cast says so to the type checker.
    for bad in ("pose", ["velocity", "pose"], [], ["velocity", "velocity"]):
        with pytest.raises(ValueError, match="critic_inputs"):
            SamplerStageConfig(critic_inputs=cast(tuple[str, ...], bad))
    # A single name (configs written before critics became a list) is one critic.
    assert SamplerStageConfig(critic_inputs=cast(tuple[str, ...], "velocity")).critic_inputs == ("velocity",)
    listed = cast(tuple[str, ...], ["dynamics", "acceleration"])
    assert SamplerStageConfig(critic_inputs=listed).critic_inputs == ("dynamics", "acceleration")


def test_changed_control_settings_are_checked():
    import pytest

    from model.train.sampler_config import SamplerStageConfig

    for bad in ({"control_batch": -1}, {"control_dt": 0.5}, {"control_shift": -1.0}):
        with pytest.raises(ValueError, match="control"):
            SamplerStageConfig(**bad)


def test_the_cross_style_critic_weight_defaults_to_w_style_and_is_checked():
    import pytest

    from model.train.sampler_config import SamplerStageConfig, cross_style_weights

    weights = {"pos": 1.0, "style": 0.15, "last_pos": 1.0}
    assert cross_style_weights(weights, SamplerStageConfig(w_style=0.15)) == weights
    assert cross_style_weights(weights, SamplerStageConfig(w_style=0.15, w_cross_style=0.6)) == {**weights, "style": 0.6}
    with pytest.raises(ValueError, match="w_cross_style"):
        SamplerStageConfig(w_cross_style=-0.1)


def test_critic_logits_match_the_critics_own_features_of_the_real_motion():
    """The critics read velocities only, so the stand-in rotations of ``critic_logits`` must change
    nothing against the real rotations; and every critic of the list answers."""
    from model.data.synthetic import synthetic_walk
    from model.motion.kinematics import forward_kinematics
    from model.nets.style_classifier import StyleClassifier, StyleClassifierConfig, motion_features
    from model.train.sampler_losses import critic_logits

    clip = synthetic_walk(frames=41)
    sk = clip.skeleton
    pos, grot = forward_kinematics(clip.rotations.float(), clip.root_positions.float(), sk.offsets_tensor(), sk.parents)
    torch.manual_seed(0)
    critics = [StyleClassifier(StyleClassifierConfig(styles=["a", "b"], joints=sk.num_joints, inputs=i)).eval()
               for i in ("dynamics", "acceleration")]
    got = critic_logits(critics, pos[None], sk)
    assert len(got) == 2
    for critic, logits in zip(critics, got):
        assert torch.allclose(logits, critic(motion_features(pos[None], grot[None], sk)), atol=1e-5)


def test_foot_slide_loss_over_frames_is_the_mean_of_its_per_frame_values():
    # transition_losses scores all generated frames at once; each frame keeps its own contact weighting.
    from model.nets.pose_state import PoseState
    from model.train.batches import foot_slide_loss

    gen = torch.Generator().manual_seed(0)
    b, frames, joints = 3, 4, 5
    states = PoseState(torch.randn(b, frames, joints, 3, generator=gen), torch.randn(b, frames, joints, 3, generator=gen),
                       torch.randn(b, frames, joints, 6, generator=gen), torch.randn(b, frames, 2, generator=gen))
    contacts = torch.rand(b, frames, 2, generator=gen)
    contacts[:, 1] = 0.0  # a frame with no planted foot counts as 0, not as a division by zero
    feet = [2, 4]
    per_frame = [foot_slide_loss(states.index((slice(None), t)), contacts[:, t], feet) for t in range(frames)]
    assert per_frame[1] == 0
    assert torch.isclose(foot_slide_loss(states, contacts, feet), torch.stack(per_frame).mean(), rtol=1e-6)


def _tiny_setup():
    """Two synthetic walk styles, a tiny sampler with labelled phases, a critic, and a 12-frame length."""
    from model.data.synthetic import synthetic_walk
    from model.nets.manifold import ManifoldConfig, ManifoldDecoder
    from model.nets.phase import PeriodicAutoencoder, PhaseConfig
    from model.nets.sampler import SamplerConfig, TransitionSampler
    from model.nets.style_classifier import StyleClassifier, StyleClassifierConfig
    from model.train.motion_tensors import MotionTensors
    from model.train.phase_stage import label_tensors
    from model.train.sampler_config import SamplerStageConfig
    from model.train.sampler_stage import style_statistics

    walks = [synthetic_walk(frames=80, speed_cm_s=v, cadence_hz=f) for v, f in ((100.0, 0.8), (160.0, 1.2))]
    sk = walks[0].skeleton
    tensors = MotionTensors.from_clips([(w, i, "walk") for i, w in enumerate(walks)], ["slow", "fast"], sk, augment=False,
                                       progress=False)
    torch.manual_seed(0)
    j = sk.num_joints
    label_tensors(PeriodicAutoencoder(PhaseConfig(channels=j * 3, phases=4, window=15, hidden=8)).eval(), tensors, False)
    sampler = TransitionSampler(SamplerConfig(joints=j, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32,
                                              root=sk.roles.root),
                                ManifoldDecoder(ManifoldConfig(joints=j, phases=4, latent=8, experts=3, hidden=32,
                                                               gate_hidden=16, encoder_hidden=32, root=sk.roles.root)))
    stage = SamplerStageConfig(style_frames=20, style_loss_min_frames=5)
    mean, std = style_statistics(tensors, 20)
    sampler.style_mean.copy_(mean)
    sampler.style_std.copy_(std)
    critics = [StyleClassifier(StyleClassifierConfig(styles=["slow", "fast"], joints=j, inputs="dynamics")).eval()]
    take_starts = [int(tensors.take_slice(i).start) for i in range(2)]
    return tensors, sampler, stage, critics, take_starts, 12


def _clips(tensors, starts: list[int]) -> torch.Tensor:
    from model.motion.features import local_frame_features

    pos, rot = tensors.gather(torch.tensor(starts), 20)
    return local_frame_features(pos, rot, tensors.skeleton)


def test_cross_style_windows_in_the_batch_rollout_score_as_in_a_rollout_of_their_own():
    """The sampler stage generates its cross-style windows in the same rollout as the batch's own windows;
    each group's losses must be those of a separate rollout (windows do not interact)."""
    from model.train.batches import make_batch
    from model.train.sampler_losses import score_rollout, transition_losses
    from model.train.sampler_rollout import concat_batches, rollout

    tensors, sampler, stage, critics, take_starts, length = _tiny_setup()
    sk, k = tensors.skeleton, sampler.config.context
    own = make_batch(tensors, torch.tensor([take_starts[0] + 3, take_starts[0] + 9]), torch.tensor([0, 0]), k + length, k - 1)
    cross = make_batch(tensors, torch.tensor([take_starts[1] + 4]), torch.tensor([1]), k + length, k - 1)

    own_clips = _clips(tensors, [take_starts[0] + 40, take_starts[0] + 50])
    cross_clips = _clips(tensors, [take_starts[0] + 30])
    ground = torch.tensor([0.0] * len(sk.feet))
    labels, xlabels = torch.tensor([0, 0]), torch.tensor([0])  # the cross window asks for the clip's style: slow
    with torch.no_grad():
        alone = transition_losses(sampler, tensors, own, own_clips, length, stage, None, False, critics, labels, ground=ground)
        xalone = transition_losses(sampler, tensors, cross, cross_clips, length, stage, None, False, critics, xlabels,
                                   ground_truth=False, ground=ground)
        r = rollout(sampler, tensors, concat_batches(own, cross), torch.cat([own_clips, cross_clips]), length, stage, None, False)
        together = score_rollout(r, tensors, stage, slice(0, 2), critics, labels, ground=ground)
        xtogether = score_rollout(r, tensors, stage, slice(2, None), critics, xlabels, ground_truth=False, ground=ground)
    assert together.keys() == alone.keys() and xtogether.keys() == xalone.keys() == {"last_pos", "last_rot", "foot_height",
                                                                                     "style", "style_acc"}
    for a, b in ((alone, together), (xalone, xtogether)):
        for key in a:
            assert torch.allclose(a[key], b[key], rtol=1e-4, atol=1e-6), key


@pytest.mark.slow  # torch.compile builds C++ with g++
def test_compiled_steps_give_the_eager_losses_and_gradients_and_restore_the_model():
    """Training with ``--compile`` runs the per-frame functions through torch.compile; the losses and the
    gradients must be those of eager execution (to float rounding), and the model must be plain afterwards."""
    import pytest

    from model.train.batches import make_batch
    from model.train.sampler_losses import transition_losses, weighted_sum
    from model.train.step_compiler import compile_unavailable, compiled_steps

    reason = compile_unavailable(torch.device("cpu"))
    if reason:
        pytest.skip(reason)
    tensors, sampler, stage, critics, take_starts, length = _tiny_setup()
    k = sampler.config.context
    batch = make_batch(tensors, torch.tensor([take_starts[0] + 3, take_starts[1] + 9]), torch.tensor([0, 1]), k + length, k - 1)
    clips = _clips(tensors, [take_starts[0] + 40, take_starts[1] + 30])
    for p in sampler.decoder.parameters():
        p.requires_grad_(False)
    params = [p for p in sampler.parameters() if p.requires_grad]
    weights = {"pos": 1.0, "rot": 1.0, "fk": 0.5, "foot": 0.1, "phase": 0.5, "last_pos": 1.0, "style": 0.1}

    def run() -> tuple[dict[str, torch.Tensor], list[torch.Tensor]]:
        losses = transition_losses(sampler, tensors, batch, clips, length, stage, torch.Generator().manual_seed(3), True,
                                   critics, torch.tensor([0, 1]))
        grads = torch.autograd.grad(weighted_sum(losses, weights), params, allow_unused=True)
        return {key: v.detach() for key, v in losses.items()}, [torch.zeros_like(p) if g is None else g
                                                                 for p, g in zip(params, grads)]

    eager_losses, eager_grads = run()
    with compiled_steps(sampler) as compiled:
        assert compiled
        assert "step" in vars(sampler)
        losses, grads = run()
    assert "step" not in vars(sampler) and "_core" not in vars(sampler)
    for key, value in eager_losses.items():
        assert torch.allclose(value, losses[key], rtol=1e-4, atol=1e-6), key
    scale = max(g.abs().max() for g in eager_grads)
    for a, b in zip(eager_grads, grads):
        assert (a - b).abs().max() <= 1e-4 * scale
    with compiled_steps(sampler, enabled=False) as compiled:
        assert not compiled and "step" not in vars(sampler)


def test_clip_acceleration_loss_needs_no_ground_truth_and_reaches_the_sampler():
    """Other-style windows have no ground truth; ``clip_acc`` compares each joint's mean acceleration over
    the generated transition with the style clip's, and its gradient reaches the sampler."""
    from model.train.batches import make_batch
    from model.train.sampler_losses import acceleration_profile, score_rollout
    from model.train.sampler_rollout import rollout

    tensors, sampler, stage, critics, take_starts, length = _tiny_setup()
    k = sampler.config.context
    batch = make_batch(tensors, torch.tensor([take_starts[0] + 3, take_starts[1] + 9]), torch.tensor([0, 1]), k + length, k - 1)
    r = rollout(sampler, tensors, batch, _clips(tensors, [take_starts[1] + 30, take_starts[0] + 40]), length, stage, None, False)
    own = acceleration_profile(torch.diff(torch.cat([r.before, r.pred_fk], 1), dim=1)).detach()
    same = score_rollout(r, tensors, stage, ground_truth=False, clip_acc=own)
    assert set(same) == {"last_pos", "last_rot", "clip_acc"} and float(same["clip_acc"]) < 1e-6
    clip_pos, _ = tensors.gather(torch.tensor([take_starts[1] + 30, take_starts[0] + 40]), 20)
    clip_acc = acceleration_profile(torch.diff(clip_pos, dim=1))
    assert clip_acc.shape == own.shape
    loss = score_rollout(r, tensors, stage, ground_truth=False, clip_acc=clip_acc)["clip_acc"]
    assert float(loss) > 0
    loss.backward()
    assert sampler.head_out[-1].weight.grad is not None and sampler.head_out[-1].weight.grad.abs().sum() > 0


def test_a_steered_rollout_lands_its_root_on_a_moved_target_and_still_trains():
    """With ``steering_window`` the rollout is steered as the engine steers: a target moved 30 cm
    away is reached by the root on the last frame, and the losses still back-propagate (through the
    network's own output; the shift carries no gradient)."""
    from dataclasses import replace

    from model.train.batches import make_batch
    from model.train.sampler_rollout import rollout

    tensors, sampler, stage, critics, take_starts, length = _tiny_setup()
    k = sampler.config.context
    batch = make_batch(tensors, torch.tensor([take_starts[0] + 3, take_starts[1] + 9]), torch.tensor([0, 1]), k + length, k - 1)
    clips = _clips(tensors, [take_starts[0] + 40, take_starts[1] + 40])
    moved = torch.tensor([[30.0, 0.0], [0.0, -30.0]])
    ends = []
    for window in (0, length):
        r = rollout(sampler, tensors, batch, clips, length, replace(stage, steering_window=window), None, False,
                    target_shift=moved)
        ends.append((r.last.root_xz - r.target.root_xz).norm(dim=-1))
        if window:
            r.pred_fk.square().mean().backward()
            assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in sampler.parameters())
    plain, steered = ends
    assert plain.max() > 10.0  # the random network alone misses
    assert (steered < 1e-3).all()

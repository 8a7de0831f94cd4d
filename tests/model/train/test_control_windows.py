"""What a game sends: a target without its velocity (the sampler's flag), and the changed-control
windows (turned and sideways-moved targets) that train for it; seeding a run from a bundle."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import write_synthetic_dataset
from model.inference.bundle import Bundle
from model.motion.rotations import quat_mul, quat_to_sixd, sixd_to_quat, yaw_quat
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerConfig, SamplerState, TransitionSampler
from model.train.from_bundle import sampler_from_bundle
from model.train.pipeline import TrainConfig, fit_to_skeleton
from model.train.presets import preset_dict
from model.train.sampler_config import SamplerStageConfig
from model.train.sampler_rollout import turn_target
from model.train.sampler_stage import trained_parameters
from rsmt_cli.main import main
from tests.model.motion.rotation_angle import quat_angle
from tests.model.tiny_bundles import MANIFOLD, SAMPLER, tiny_bundle

pytestmark = pytest.mark.usefixtures("one_thread")

J = SAMPLER.joints
FLAGGED = SamplerConfig(**{**SAMPLER.to_dict(), "target_velocity_flag": True})


def random_targets(b: int, seed: int) -> PoseState:
    gen = torch.Generator().manual_seed(seed)
    q = torch.randn(b, J, 4, generator=gen)
    return PoseState(torch.randn(b, J, 3, generator=gen) * 30, torch.randn(b, J, 3, generator=gen),
                     quat_to_sixd(q / q.norm(dim=-1, keepdim=True)), torch.randn(b, 2, generator=gen) * 100)


def test_the_flag_zeroes_an_unknown_velocity_and_older_samplers_ignore_it():
    flagged = TransitionSampler(FLAGGED,
                                tiny_bundle(0).sampler.decoder)
    t = random_targets(3, 0)
    vec = flagged.target_input(t, torch.tensor([True, False, True]))
    assert vec.shape == (3, 12 * J + 1)
    assert vec[:, -1].tolist() == [1.0, 0.0, 1.0]
    assert torch.equal(vec[1, 3 * J:6 * J], torch.zeros(3 * J)) and torch.equal(vec[0, :-1], t.vector()[0])
    assert torch.equal(flagged.target_input(t)[:, -1], torch.ones(3))  # None: every velocity known
    plain = tiny_bundle(0).sampler
    assert torch.equal(plain.target_input(t, torch.tensor([False, False, False])), t.vector())


@settings(max_examples=25, deadline=None)
@given(angle=st.floats(-math.pi, math.pi), seed=st.integers(0, 1000))
def test_a_turned_target_keeps_its_place_and_heights_and_turns_by_the_angle(angle, seed):
    t = random_targets(2, seed)
    a = torch.full((2,), angle)
    turned = turn_target(t, a)
    assert torch.equal(turned.root_xz, t.root_xz)
    assert torch.allclose(turned.rel[..., 1], t.rel[..., 1], atol=1e-4)  # heights
    assert torch.allclose(turned.rel.norm(dim=-1), t.rel.norm(dim=-1), atol=1e-3)
    # Every joint's global rotation is the yaw times the old one.
    want = quat_mul(yaw_quat(a).view(2, 1, 4).expand(2, J, 4), sixd_to_quat(t.rot))
    assert quat_angle(sixd_to_quat(turned.rot), want).max() < 1e-3
    back = turn_target(turned, -a)
    assert torch.allclose(back.rel, t.rel, atol=1e-3) and torch.allclose(back.vel, t.vel, atol=1e-4)


def test_control_settings_are_checked():
    overrides: tuple[dict[str, Any], ...] = ({"control_turn": -1.0}, {"control_side": -5.0})
    for bad in overrides:
        with pytest.raises(ValueError, match="control"):
            SamplerStageConfig(**bad)
    for bad_drop in (-0.1, 1.5):
        with pytest.raises(ValueError, match="target_velocity_drop"):
            SamplerStageConfig(target_velocity_drop=bad_drop)


def smoke_config(**stage) -> dict:
    cfg = preset_dict("smoke")
    cfg["sampler"]["target_velocity_flag"] = True
    cfg["sampler_stage"]["loop"].update(iterations=8, epoch_iterations=4)
    cfg["sampler_stage"].update(stage)
    return cfg


@pytest.mark.slow  # trains a sampler stage from a bundle
def test_a_run_seeded_from_a_bundle_trains_with_unknown_velocities_and_turned_targets(tmp_path, monkeypatch):
    """``rsmt train sampler --from-bundle`` writes the bundle's stages into the run folder, the flag's
    column starts at zero (the same output for targets with their velocity), and the stage then trains
    from the given step with dropped velocities, all three kinds of changed-control windows and steered
    rollouts."""
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    raw = smoke_config(target_velocity_drop=0.5, control_batch=6, control_turn=90.0, control_side=50.0, steering_window=6)
    cfg = TrainConfig.from_dict(raw)
    sk = tiny_bundle(0).skeleton
    fit_to_skeleton(cfg, sk.num_joints, sk.roles.root)
    plain = SamplerConfig(**{**cfg.sampler.to_dict(), "target_velocity_flag": False})
    source = Bundle.create(sk, plain, cfg.manifold, cfg.phase, seed=3)
    source.save(tmp_path / "source")
    path = tmp_path / "control.json"
    path.write_text(json.dumps(raw))
    args = ["train", "sampler", "--config", str(path), "--data", str(data), "--out", str(tmp_path / "out"),
            "--run", str(tmp_path / "run"), "--from-bundle", str(tmp_path / "source"), "--at-step", "4", "--quiet"]
    assert main(args) == 0
    history = json.loads((tmp_path / "run" / "sampler" / "checkpoint.json").read_text())["history"]
    assert [h["step"] for h in history] == [8]  # started at step 4
    assert history[-1]["train_control_last"] > 0
    tuned = Bundle.load(tmp_path / "out")
    assert tuned.config.target_velocity_flag
    t = random_targets(2, 1)
    with torch.no_grad():
        seeded = sampler_from_bundle(Bundle.load(tmp_path / "source"), cfg)
        assert torch.allclose(seeded.target_encoder(seeded.target_input(t)),
                              source.sampler.target_encoder(source.sampler.target_input(t)), atol=1e-6)
    # A second run finds the checkpoint and resumes it instead of seeding again.
    assert main(args) == 0


def test_seeding_refuses_a_bundle_of_another_shape(tmp_path):
    from model.train.from_bundle import seed_run

    tiny_bundle(0).save(tmp_path / "tiny")
    cfg = TrainConfig.from_dict(smoke_config())  # smoke's sampler is not the tiny bundle's
    with pytest.raises(ValueError, match="differs"):
        seed_run(tmp_path / "tiny", cfg, tmp_path / "run", 4)
    assert not (tmp_path / "run").exists()


def test_the_engine_tells_a_flagged_model_whether_the_target_came_with_its_velocity():
    from model.data.synthetic import synthetic_walk
    from model.inference.engine import Engine

    flagged = Bundle.create(tiny_bundle(0).skeleton, FLAGGED,
                            MANIFOLD, seed=1)
    engine = Engine(flagged)
    walk = synthetic_walk(frames=80)
    style, _ = engine.encode_style(walk.window(20, 60))
    one = engine.prepare(walk.window(0, 10), walk.window(39, 40), 12, style, deterministic=True)
    two = engine.prepare(walk.window(0, 10), walk.window(38, 40), 12, style, deterministic=True)
    starts = [None if c.parked is None else c.parked.prepared for c in (one, two)]
    assert [None if s is None else s.velocity_known for s in starts] == [False, True]
    row = engine.begin([one, two])
    assert isinstance(row, SamplerState)
    assert row.target_vec[:, -1].tolist() == [0.0, 1.0]
    assert torch.equal(row.target_vec[0, 3 * J:6 * J], torch.zeros(3 * J))
    ch = engine.prepare(walk.window(0, 10), walk.window(38, 40), 12, style, deterministic=True)
    engine.retarget(ch, target=walk.window(50, 51))
    held = None if ch.parked is None else ch.parked.row
    assert isinstance(held, SamplerState) and held.target_vec[0, -1].item() == 0.0
    rot, _ = engine.generate([engine.prepare(walk.window(0, 10), walk.window(39, 40), 12, style, deterministic=True)])[0]
    assert rot.shape[0] == 12


def test_a_checkpoint_without_the_flag_grows_its_column_and_moments_and_resumes(tmp_path):
    """The shipped recipe's stage F goes on from E3's checkpoint in the same run folder, with the flag."""
    from model.train.loop import LoopConfig, load_checkpoint, make_optimizer, save_checkpoint
    from model.train.velocity_flag import FLAG_KEY, widen_checkpoint

    old = tiny_bundle(0).sampler
    params = trained_parameters(old)
    opt = make_optimizer(params, LoopConfig())
    torch.stack([p.sum() for _, p in params]).sum().backward()  # one step, so the moments exist
    opt.step()
    save_checkpoint(tmp_path, old, opt, 7, [{"step": 7}])
    flagged = TransitionSampler(FLAGGED, old.decoder)
    assert widen_checkpoint(tmp_path, flagged)
    assert not widen_checkpoint(tmp_path, flagged)  # grown once
    new_params = trained_parameters(flagged)
    new_opt = make_optimizer(new_params, LoopConfig())
    restored = load_checkpoint(tmp_path, flagged, new_opt)
    assert restored is not None and restored[0] == 7
    weight = dict(flagged.named_parameters())[FLAG_KEY]
    assert torch.equal(weight[:, -1], torch.zeros(weight.shape[0]))
    assert torch.equal(new_opt.state[weight]["exp_avg"][:, -1], torch.zeros(weight.shape[0]))
    t = random_targets(2, 5)
    with torch.no_grad():
        assert torch.allclose(flagged.target_encoder(flagged.target_input(t)), old.target_encoder(old.target_input(t)))

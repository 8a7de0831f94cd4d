"""Few-shot fine-tuning: what each scope trains, kept as an adapter beside weights left as they were."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.bundle_adapters import StyleAdapter
from model.nets.manifold import ManifoldConfig
from model.nets.phase import PhaseConfig
from model.nets.sampler import SamplerConfig
from model.train.finetune import FROZEN_PREFIXES, STYLE_PREFIXES, FinetuneConfig, check_clips, finetune_style
from model.train.loop import LoopConfig, LoopResult


@pytest.fixture()
def bundle() -> Bundle:
    torch.set_num_threads(1)
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Bundle.create(synthetic_skeleton(), cfg, man, PhaseConfig(channels=63, phases=4, window=15, hidden=8))


def _clips():
    return [synthetic_walk(frames=60, cadence_hz=1.5, stride_deg=35.0, turn_deg_s=t) for t in (0.0, 30.0, -30.0)]


def _config(scope: str, **extra) -> FinetuneConfig:
    ft = FinetuneConfig.for_scope(scope)
    ft.loop = LoopConfig(iterations=4, epoch_iterations=2, warmup=1, lr=ft.loop.lr, lr_final=ft.loop.lr_final)
    ft.batch, ft.max_transition, ft.style_frames = 4, 12, 40
    for k, v in extra.items():
        setattr(ft, k, v)
    return ft


def _changed(bundle: Bundle, run: Callable[[], tuple[StyleAdapter, LoopResult]]
             ) -> tuple[set[str], StyleAdapter, LoopResult]:
    before = {k: v.clone() for k, v in bundle.sampler.state_dict().items()}
    adapter, result = run()
    assert all(torch.equal(v, before[k]) for k, v in bundle.sampler.state_dict().items())  # left as it was
    return set(adapter.tensors), adapter, result


def test_the_style_scope_touches_only_style_layers(bundle, tmp_path):
    changed, adapter, result = _changed(bundle, lambda: finetune_style(bundle, _clips(), "bouncy", _config("style"),
                                                                          tmp_path / "run", progress=False))
    assert result.finished and len(result.history) == 2
    assert changed and all(n.startswith(STYLE_PREFIXES) for n in changed)
    assert any(n.startswith("style_encoder.") for n in changed)
    assert adapter.name == "bouncy" and adapter.base_version == bundle.version
    assert "FiLM/attention linears only" in adapter.notes


def test_the_network_scope_trains_the_core_but_never_the_manifold(bundle, tmp_path):
    changed, adapter, _ = _changed(bundle, lambda: finetune_style(bundle, _clips(), "bouncy", _config("network"),
                                                                     tmp_path / "run", progress=False))
    assert any(n.startswith("lstm.") for n in changed) and any(n.startswith("head_out.") for n in changed)
    assert not any(n.startswith(FROZEN_PREFIXES) for n in changed)
    assert "every sampler weight but the manifold decoder" in adapter.notes
    # Resumed from its checkpoints, the same run gives the same adapter.
    again, _ = finetune_style(bundle, _clips(), "bouncy", _config("network"), tmp_path / "run", progress=False)
    assert again.version == adapter.version


def test_each_scope_has_the_defaults_it_was_measured_with() -> None:
    network, style = FinetuneConfig.for_scope("network"), FinetuneConfig.for_scope("style")
    assert (network.loop.iterations, network.loop.lr, network.loop.lr_final, network.w_foot, network.blend) == (
        400, 3e-4, 3e-5, 1.0, 0.5)
    assert (style.loop.iterations, style.loop.lr, style.loop.lr_final, style.w_foot, style.blend) == (
        300, 3e-4, 3e-5, 0.05, 1.0)


def test_an_unknown_scope_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown fine-tuning scope"):
        FinetuneConfig.for_scope("everything")


def test_the_generated_feet_term_changes_what_is_learned_only_when_weighed(bundle, tmp_path, monkeypatch):
    """``w_foot_height`` adds the generated feet's speed at their ground height (the clips' ground levels) to
    the objective: weighed, the tuned weights differ; at 0 (the default) the term is not computed and the run
    is the one it always was. An untrained network's generated feet hover above the ground, where the term
    is 0, so here every generated foot counts as planted."""
    import model.train.sampler_losses as losses

    seen: list = []

    def every_foot_planted(positions, feet, ground):
        seen.append(ground)
        p = positions[:, :, feet]
        return (p[:, 1:, :, [0, 2]] - p[:, :-1, :, [0, 2]]).pow(2).sum(-1).add(1e-6).sqrt().mean()

    monkeypatch.setattr(losses, "planted_foot_speed", every_foot_planted)
    plain, _ = finetune_style(bundle, _clips(), "bouncy", _config("network"), tmp_path / "a", progress=False)
    assert not seen and FinetuneConfig().w_foot_height == 0.0
    held, _ = finetune_style(bundle, _clips(), "bouncy", _config("network", w_foot_height=5.0), tmp_path / "c",
                             progress=False)
    assert seen and seen[0].shape == (len(bundle.skeleton.feet),)
    assert held.version != plain.version


def test_how_often_it_validates_never_changes_what_is_learned(bundle, tmp_path):
    """The default validates once, at the end: validations do not touch the training steps, so the adapter is
    the same to the bit as with a validation every step."""
    assert FinetuneConfig().loop.epoch_iterations == FinetuneConfig().loop.iterations
    every_step = _config("network")
    every_step.loop.epoch_iterations = 1
    at_the_end = _config("network")
    at_the_end.loop.epoch_iterations = at_the_end.loop.iterations
    a, ra = finetune_style(bundle, _clips(), "bouncy", every_step, tmp_path / "a", progress=False)
    b, rb = finetune_style(bundle, _clips(), "bouncy", at_the_end, tmp_path / "b", progress=False)
    assert len(ra.history) == 4 and len(rb.history) == 1
    assert a.version == b.version


def test_a_clip_too_short_is_named(bundle, tmp_path):
    short = synthetic_walk(frames=12, cadence_hz=1.5, stride_deg=35.0)
    clips = [*_clips()[:2], replace(short, name="tiny.bvh")]
    with pytest.raises(ValueError, match=r"tiny\.bvh is too short: 12 frames at 30 fps; each clip needs at least 16"):
        check_clips(bundle, clips, FinetuneConfig())
    with pytest.raises(ValueError, match="too short"):
        finetune_style(bundle, clips, "bouncy", _config("network"), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()

"""Few-shot fine-tuning: what each scope trains, and rehearsal of the known styles."""

from __future__ import annotations

import pytest
import torch

from model.data.preprocessed import load_motion_cache
from model.data.synthetic import synthetic_skeleton, synthetic_walk, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.nets.manifold import ManifoldConfig
from model.nets.phase import PhaseConfig
from model.nets.sampler import SamplerConfig
from model.train.finetune import FROZEN_PREFIXES, STYLE_PREFIXES, FinetuneConfig, finetune_style
from model.train.loop import LoopConfig
from model.train.motion_tensors import MotionTensors


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


def _changed(before: Bundle, after: Bundle) -> set[str]:
    old = dict(before.sampler.named_parameters())
    return {n for n, p in after.sampler.named_parameters() if not torch.equal(p, old[n])}


def test_the_style_scope_touches_only_style_layers(bundle, tmp_path):
    tuned, result = finetune_style(bundle, _clips(), "bouncy", _config("style"), tmp_path / "run", progress=False)
    assert result.finished and len(result.history) == 2
    changed = _changed(bundle, tuned)
    assert changed and all(n.startswith(STYLE_PREFIXES) for n in changed)
    assert any(n.startswith("style_encoder.") for n in changed)
    assert tuned.meta.name.endswith("+bouncy") and "FiLM/attention linears only" in tuned.meta.notes
    tuned.save(tmp_path / "tuned")
    assert Bundle.load(tmp_path / "tuned").version != "unsaved"


def test_the_network_scope_trains_the_core_but_never_the_manifold(bundle, tmp_path):
    tuned, _ = finetune_style(bundle, _clips(), "bouncy", _config("network"), tmp_path / "run", progress=False)
    changed = _changed(bundle, tuned)
    assert any(n.startswith("lstm.") for n in changed) and any(n.startswith("head_out.") for n in changed)
    assert not any(n.startswith(FROZEN_PREFIXES) for n in changed)
    assert "every sampler weight but the manifold decoder" in tuned.meta.notes


def test_rehearsal_trains_on_the_known_styles_beside_the_clips(bundle, tmp_path):
    data = tmp_path / "data"
    write_synthetic_dataset(data, takes_per_pair=2, frames=120)
    cache = load_motion_cache(data, root=tmp_path / "cache", workers=1, progress=False)
    known = [i for i in cache.split.train if cache.takes[i].style != "bouncy"]
    motion = MotionTensors.from_cache(cache, known, bundle.skeleton, augment=False, progress=False)
    tuned, result = finetune_style(bundle, _clips(), "bouncy", _config("network"), tmp_path / "run", progress=False,
                                   rehearsal=motion)
    assert result.finished and "rehearsing brisk, slow" in tuned.meta.notes
    # The known styles' windows change what is learned; with no rehearsal batch they are not read.
    plain, _ = finetune_style(bundle, _clips(), "bouncy", _config("network"), tmp_path / "run2", progress=False)
    unread, _ = finetune_style(bundle, _clips(), "bouncy", _config("network", rehearsal_batch=0), tmp_path / "run3",
                               progress=False, rehearsal=motion)
    weights = {name: dict(b.sampler.named_parameters())["lstm.weight_ih"] for name, b in
               (("rehearsed", tuned), ("plain", plain), ("unread", unread))}
    assert not torch.equal(weights["rehearsed"], weights["plain"])
    assert torch.equal(weights["unread"], weights["plain"]) and "rehearsing" not in unread.meta.notes


def test_an_unknown_scope_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown fine-tuning scope"):
        FinetuneConfig.for_scope("everything")

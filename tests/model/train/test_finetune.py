"""Few-shot fine-tuning changes only the style encoder and the FiLM/attention layers."""

from __future__ import annotations

import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.nets.manifold import ManifoldConfig
from model.nets.phase import PhaseConfig
from model.nets.sampler import SamplerConfig
from model.train.finetune import TRAINABLE_PREFIXES, FinetuneConfig, finetune_style
from model.train.loop import LoopConfig


def test_finetune_touches_only_style_layers(tmp_path):
    torch.set_num_threads(1)
    cfg = SamplerConfig(joints=21, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=20)
    man = ManifoldConfig(joints=21, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man, PhaseConfig(channels=63, phases=4, window=15, hidden=8))
    clips = [synthetic_walk(frames=60, cadence_hz=1.5, stride_deg=35.0, turn_deg_s=t) for t in (0.0, 30.0, -30.0)]
    ft = FinetuneConfig(loop=LoopConfig(iterations=4, epoch_iterations=2, warmup=1), batch=4, max_transition=12, style_frames=40)
    tuned, result = finetune_style(bundle, clips, "bouncy", ft, tmp_path / "run", progress=False)
    assert result.finished and len(result.history) == 2
    before = dict(bundle.sampler.named_parameters())
    changed = {n for n, p in tuned.sampler.named_parameters() if not torch.equal(p, before[n])}
    assert changed and all(n.startswith(TRAINABLE_PREFIXES) for n in changed)
    assert any(n.startswith("style_encoder.") for n in changed)
    assert tuned.meta.name.endswith("+bouncy")
    tuned.save(tmp_path / "tuned")
    assert Bundle.load(tmp_path / "tuned").version != "unsaved"

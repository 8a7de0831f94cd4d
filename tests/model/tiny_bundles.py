"""Tiny untrained bundles on the synthetic 21-joint skeleton, for tests of commands that only copy,
mix or convert weights (their outputs are never judged as motion)."""

from __future__ import annotations

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig

J = 21
SAMPLER = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32)
MANIFOLD = ManifoldConfig(joints=J, phases=4, latent=8, experts=3, hidden=32, gate_hidden=16, encoder_hidden=32)


def tiny_bundle(seed: int, sampler: SamplerConfig = SAMPLER) -> Bundle:
    """A bundle with weights drawn from ``seed``; ``sampler`` changes its shape."""
    return Bundle.create(synthetic_skeleton(), sampler, MANIFOLD, seed=seed)

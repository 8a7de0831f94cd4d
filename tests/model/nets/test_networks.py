"""Checks every network shares: shapes, save -> load gives the same output, seeds repeat, and a
batch of N gives what N batches of one give."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle, BundleError
from model.nets.manifold import ManifoldConfig, ManifoldDecoder, MixtureLinear, MotionManifold
from model.nets.phase import (
    PeriodicAutoencoder,
    PhaseConfig,
    PhaseEstimator,
    advance_phase,
    blend_phase,
    label_phases,
    phase_vectors,
    same_conv_fft,
)
from model.nets.pose_state import PoseState, state_dim, state_from_positions
from model.nets.sampler import SamplerConfig, SamplerState, StyleContext, TransitionSampler

J = 21
TINY_SAMPLER = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32)
TINY_MANIFOLD = ManifoldConfig(joints=J, phases=4, latent=8, experts=3, hidden=32, gate_hidden=16, encoder_hidden=32)


def _pose(b: int, seed: int = 0) -> PoseState:
    g = torch.Generator().manual_seed(seed)
    pos = torch.randn(b, 3, J, 3, generator=g) * 30
    rot = torch.randn(b, 3, J, 6, generator=g)
    return state_from_positions(pos, rot).index((slice(None), 2))


def _sampler(seed: int = 0) -> TransitionSampler:
    torch.manual_seed(seed)
    return TransitionSampler(TINY_SAMPLER, ManifoldDecoder(TINY_MANIFOLD)).eval()


def test_mixture_linear_matches_explicit_blend():
    layer = MixtureLinear(5, 4, 3)
    x = torch.randn(6, 5)
    alpha = torch.softmax(torch.randn(6, 3), -1)
    w = layer.weight.view(5, 3, 4)
    b = layer.bias.view(3, 4)
    expected = torch.stack([sum((alpha[i, e] * (x[i] @ w[:, e] + b[e]) for e in range(3)), torch.zeros(4))
                            for i in range(6)])
    assert torch.allclose(layer(x, alpha), expected, atol=1e-5)


def test_decoder_shapes_and_batching():
    dec = ManifoldDecoder(TINY_MANIFOLD).eval()
    state = _pose(5)
    z, ph = torch.randn(5, 8), torch.randn(5, 4, 2)
    rv, rr = torch.randn(5, 3), torch.randn(5, 6)
    nxt = dec.step(state, rv, rr, z, ph)
    assert nxt.rel.shape == (5, J, 3) and nxt.rot.shape == (5, J, 6)
    assert torch.allclose(nxt.vel[:, 0], rv)  # the root's motion is imposed
    for i in range(5):
        one = dec.step(state.index(slice(i, i + 1)), rv[i : i + 1], rr[i : i + 1], z[i : i + 1], ph[i : i + 1])
        assert torch.allclose(one.rel, nxt.rel[i : i + 1], atol=1e-4)
        assert torch.allclose(one.rot, nxt.rot[i : i + 1], atol=1e-5)


def test_rotations_stay_on_the_manifold():
    dec = ManifoldDecoder(TINY_MANIFOLD).eval()
    state = _pose(3)
    for _ in range(5):
        state = dec.step(state, torch.randn(3, 3), torch.randn(3, 6), torch.randn(3, 8), torch.randn(3, 4, 2))
    a, b = state.rot[..., :3], state.rot[..., 3:]
    assert torch.allclose(a.norm(dim=-1), torch.ones(3, J), atol=1e-5)
    assert (a * b).sum(-1).abs().max() < 1e-5


def test_pae_shapes_and_labels():
    cfg = PhaseConfig(channels=J * 3, phases=4, window=15, hidden=8)
    pae = PeriodicAutoencoder(cfg).eval()
    x = torch.randn(6, J * 3, 15)
    recon, params = pae(x)
    assert recon.shape == x.shape and params["shift"].shape == (6, 4)
    assert (params["shift"].abs() <= 0.5).all()
    labels = label_phases(pae, torch.randn(40, J * 3))
    assert labels["phase"].shape == (40, 4, 2)
    assert torch.allclose(labels["phase"].norm(dim=-1), labels["amplitude"] * cfg.amplitude_scale, atol=1e-4)


@pytest.mark.parametrize("window", [15, 61])
def test_fft_encoder_matches_the_convolutions(window):
    # Labelling runs the encoder's convolutions as spectral products; they must give the conv's numbers.
    torch.manual_seed(0)
    pae = PeriodicAutoencoder(PhaseConfig(channels=J * 3, phases=4, window=window, hidden=8)).eval()
    x = torch.randn(5, J * 3, window)
    assert torch.allclose(same_conv_fft(x, pae.enc1), pae.enc1(x), atol=1e-5)
    with torch.no_grad():
        for direct, spectral in zip(pae.encode(x), pae.encode(x, fft=True)):
            assert torch.allclose(direct, spectral, atol=1e-5)
    with pytest.raises(ValueError, match="same"):
        same_conv_fft(x, torch.nn.Conv1d(J * 3, 2, 3))  # no padding: not a "same" convolution


def test_phase_update_rotates_at_frequency():
    p = phase_vectors(torch.tensor([[1.0]]), torch.tensor([[0.0]]), 1.0)
    q = advance_phase(p, torch.tensor([[2.0]]), torch.tensor([[0.25]]), 1.0)  # a quarter turn
    assert torch.allclose(q, torch.tensor([[[0.0, 2.0]]]), atol=1e-6)
    mid = blend_phase(torch.tensor([[1.0, 0.0]]), torch.tensor([[0.0, 3.0]]))
    assert torch.allclose(mid.norm(dim=-1), torch.tensor([2.0]))


def test_sampler_step_is_batch_invariant():
    net = _sampler()
    b = 4
    ctx = state_from_positions(torch.randn(b, 10, J, 3) * 30, torch.randn(b, 10, J, 6))
    target = _pose(b, 1)
    with torch.no_grad():
        style = net.style_context(net.encode_style(torch.randn(b, 40, J * 12)))
        state = net.begin(ctx, target, torch.full((b,), 20), torch.zeros(b, 64), style)
        whole, _ = net.step(state, style)
        for i in range(b):
            one, _ = net.step(state.index(slice(i, i + 1)), style.index(slice(i, i + 1)))
            assert torch.allclose(one.pose.rel, whole.pose.rel[i : i + 1], atol=1e-4)
            assert torch.allclose(one.h, whole.h[i : i + 1], atol=1e-5)


def test_styles_of_different_lengths_batch_with_masks():
    net = _sampler()
    with torch.no_grad():
        short = net.style_context(net.encode_style(torch.randn(1, 20, J * 12)))
        long = net.style_context(net.encode_style(torch.randn(1, 60, J * 12)))
        both = StyleContext.stack([short, long])
        x = torch.randn(2, 32)
        out = net.attn1.attend(x, both.keys1, both.values1, both.mask)
        alone = net.attn1.attend(x[:1], short.keys1, short.values1, short.mask)
    assert both.mask.shape == (2, long.mask.shape[1]) and not both.mask[0, -1]
    assert torch.allclose(out[:1], alone, atol=1e-5)


def test_sampler_state_stack_and_index_round_trip():
    net = _sampler()
    ctx = state_from_positions(torch.randn(3, 10, J, 3), torch.randn(3, 10, J, 6))
    with torch.no_grad():
        style = net.style_context(net.encode_style(torch.randn(3, 30, J * 12)))
        state = net.begin(ctx, _pose(3), torch.tensor([5, 6, 7]), torch.zeros(3, 64), style)
    parts = [state.index(slice(i, i + 1)) for i in range(3)]
    again = SamplerState.stack(parts)
    assert torch.equal(again.h, state.h) and torch.equal(again.pose.rot, state.pose.rot)
    assert again.tta.tolist() == [5, 6, 7]


def test_bundle_save_load_same_output(tmp_path):
    bundle = Bundle.create(synthetic_skeleton(), TINY_SAMPLER, TINY_MANIFOLD, seed=3)
    bundle.save(tmp_path / "b")
    loaded = Bundle.load(tmp_path / "b")
    assert loaded.version == bundle.version and len(loaded.version) == 16
    feats = torch.randn(1, 30, J * 12)
    with torch.no_grad():
        assert torch.equal(bundle.sampler.encode_style(feats), loaded.sampler.encode_style(feats))
    # Same seed, same weights.
    again = Bundle.create(synthetic_skeleton(), TINY_SAMPLER, TINY_MANIFOLD, seed=3)
    assert all(torch.equal(a, b) for a, b in zip(again.sampler.state_dict().values(), bundle.sampler.state_dict().values()))


def test_bundle_load_is_strict(tmp_path):
    with pytest.raises(BundleError, match="missing"):
        Bundle.load(tmp_path)
    bundle = Bundle.create(synthetic_skeleton(), TINY_SAMPLER, TINY_MANIFOLD)
    bundle.save(tmp_path / "b")
    cfg = (tmp_path / "b" / "config.json").read_text().replace('"width": 32', '"width": 48')
    (tmp_path / "b" / "config.json").write_text(cfg)
    with pytest.raises(BundleError, match="do not match"):
        Bundle.load(tmp_path / "b")


def test_phase_estimator_shapes():
    est = PhaseEstimator(state_dim(J), 10, 4)
    p, a, f = est(torch.randn(2, 10, state_dim(J)))
    assert p.shape == (2, 4, 2) and a.shape == (2, 4) and f.shape == (2, 4)


def test_manifold_encoder():
    m = MotionManifold(TINY_MANIFOLD)
    mu, logvar = m.encoder(torch.randn(2, state_dim(J)), torch.randn(2, state_dim(J)))
    assert mu.shape == (2, 8) and logvar.shape == (2, 8)


def test_half_precision_bundle_loads_as_float32(tmp_path):
    bundle = Bundle.create(synthetic_skeleton(), TINY_SAMPLER, TINY_MANIFOLD, seed=4)
    bundle.save(tmp_path / "full")
    bundle.save(tmp_path / "half", weights_dtype="float16")
    full = (tmp_path / "full" / "weights.safetensors").stat().st_size
    half = (tmp_path / "half" / "weights.safetensors").stat().st_size
    assert half < 0.6 * full
    loaded = Bundle.load(tmp_path / "half")
    p = next(loaded.sampler.parameters())
    assert p.dtype == torch.float32
    ref = dict(bundle.sampler.named_parameters())
    for n, q in loaded.sampler.named_parameters():
        assert torch.allclose(q, ref[n], atol=1e-3, rtol=1e-3)
    with pytest.raises(BundleError):
        bundle.save(tmp_path / "x", weights_dtype="int8")


def test_pose_state_cat_and_stack_round_trip():
    a, b = _pose(2, seed=1), _pose(3, seed=2)
    joined = PoseState.cat([a, b])
    assert torch.equal(joined.index(slice(2, None)).rot, b.rot) and torch.equal(joined.index(slice(0, 2)).root_xz, a.root_xz)
    frames = PoseState.stack([a, a.index(slice(None))], 1)  # [B, 2, J, *]
    assert frames.rel.shape == (2, 2, J, 3) and torch.equal(frames.index((slice(None), 1)).vel, a.vel)

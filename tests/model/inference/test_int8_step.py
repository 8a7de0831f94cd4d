"""The int8 LSTM of the per-frame step: a bundle setting, saved and loaded, close to float32, overridable."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle, BundleError
from model.inference.engine import Engine
from model.inference.int8_step import int8_lstm_sampler
from model.inference.overrides import Overrides
from model.inference.settings import InferenceConfig
from model.motion.clip import Clip
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig, TransitionSampler

J = 21


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    # rnn 128: the cell is big enough for int8 rounding to be representative of a real model's.
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=64, rnn=128, head=64, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Bundle.create(synthetic_skeleton(), cfg, man, seed=4)


def _generate(engine: Engine, walk: Clip) -> tuple[torch.Tensor, torch.Tensor]:
    style, _ = engine.encode_style(walk.window(30, 150))
    chars = [engine.prepare(walk.window(i, i + 10), walk.window(40, 42), 25, style, deterministic=True) for i in (0, 5)]
    out = engine.generate(chars)
    return torch.stack([r for r, _ in out]), torch.stack([p for _, p in out])


def test_only_the_lstm_cell_is_quantised_and_the_original_is_untouched(bundle):
    q = int8_lstm_sampler(bundle.sampler)
    assert isinstance(q, TransitionSampler)
    assert type(q.lstm).__name__ == "LSTMCell" and type(q.lstm).__module__.startswith("torch.ao.nn.quantized")
    assert isinstance(bundle.sampler.lstm, torch.nn.LSTMCell) and type(bundle.sampler.lstm).__module__ == "torch.nn.modules.rnn"
    assert isinstance(q.head_in[0], torch.nn.Linear) and q.decoder.l1.weight.dtype == torch.float32


@pytest.mark.parametrize("compiled", [True, False])
def test_int8_lstm_frames_stay_close_to_float32_and_differ_from_them(bundle, walk, compiled):
    rot32, root32 = _generate(Engine(bundle, compiled=compiled, overrides=Overrides(int8_lstm=False)), walk)
    engine = Engine(bundle, compiled=compiled, overrides=Overrides(int8_lstm=True))
    assert engine.inference.int8_lstm
    rot8, root8 = _generate(engine, walk)
    assert not torch.equal(root8, root32)  # the quantised cell really runs
    # Measured: 0.05 mm of root drift over 25 frames and 0.002 rad of joint rotation at most.
    assert (root8 - root32).norm(dim=-1).max() < 0.1
    angle = 2 * torch.acos((rot8 * rot32).sum(-1).abs().clamp(max=1.0))
    assert angle.max() < 0.02
    # Seeded int8 runs repeat exactly.
    again = _generate(Engine(bundle, compiled=compiled, overrides=Overrides(int8_lstm=True)), walk)
    assert torch.equal(again[0], rot8) and torch.equal(again[1], root8)


def test_the_setting_is_saved_with_the_bundle_and_overridable(bundle, tmp_path):
    replace(bundle, inference=InferenceConfig(int8_lstm=True)).save(tmp_path / "b")
    loaded = Bundle.load(tmp_path / "b")
    assert loaded.inference == InferenceConfig(True)
    assert Engine(loaded).inference.int8_lstm and not Engine(loaded, overrides=Overrides(int8_lstm=False)).inference.int8_lstm
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    for bad in ({"int8_lstm": "yes"}, {"int8": True}):
        cfg["inference"] = bad
        (tmp_path / "b" / "config.json").write_text(json.dumps(cfg))
        with pytest.raises(BundleError, match="inference"):
            Bundle.load(tmp_path / "b")
    del cfg["inference"]  # a bundle from before the setting existed: float32 throughout
    (tmp_path / "b" / "config.json").write_text(json.dumps(cfg))
    assert Bundle.load(tmp_path / "b").inference == InferenceConfig()
    assert not Engine(Bundle.load(tmp_path / "b")).inference.int8_lstm


def test_a_pytorch_without_quantisation_keeps_float32(bundle, monkeypatch, caplog):
    def broken(*args, **kwargs):
        raise RuntimeError("no quantized engine")

    monkeypatch.setattr(torch.ao.quantization, "quantize_dynamic", broken)
    engine = Engine(bundle, overrides=Overrides(int8_lstm=True))
    assert not engine.inference.int8_lstm
    assert "int8 LSTM unavailable" in caplog.text

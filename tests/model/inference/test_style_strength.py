"""Style strength (model/inference/style_strength.py): the neutral style, the scaling, and the engine that runs it."""

from __future__ import annotations

from dataclasses import fields

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import synthetic_walk
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import CharacterBatch, Engine
from model.inference.overrides import Overrides
from model.inference.settings import InferenceConfig
from model.inference.style_strength import NeutralStyle, check_strength
from model.nets.sampler import StyleContext

W = 4


def context(steps: int, seed: int) -> StyleContext:
    g = torch.Generator().manual_seed(seed)

    def r(*shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=g)

    return StyleContext(r(1, W), r(1, W), r(1, W, steps), r(1, steps, W), r(1, W), r(1, W), r(1, W, steps),
                        r(1, steps, W), torch.ones(1, steps, dtype=torch.bool))


def test_the_neutral_style_averages_real_steps_only():
    short, long = context(2, 0), context(5, 1)
    neutral = NeutralStyle.of([short, long]).context
    assert torch.allclose(neutral.gamma1, (short.gamma1 + long.gamma1) / 2)
    keys = torch.cat([short.keys1, long.keys1], 2)  # the 7 real steps, padding left out
    assert torch.allclose(neutral.keys1, keys.mean(2, keepdim=True))
    values = torch.cat([short.values2, long.values2], 1)
    assert torch.allclose(neutral.values2, values.mean(1, keepdim=True))
    assert neutral.keys1.shape == (1, W, 1) and neutral.values1.shape == (1, 1, W)
    with pytest.raises(ValueError, match="at least one"):
        NeutralStyle.of([])


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 4.0), st.integers(1, 6), st.integers(0, 1000))
def test_strength_moves_each_field_linearly_from_the_neutral_style(k, steps, seed):
    neutral = NeutralStyle.of([context(3, 7), context(4, 8)])
    ctx = context(steps, seed)
    out = neutral.scaled(ctx, k)
    for f in fields(ctx):
        a, b = getattr(out, f.name), getattr(ctx, f.name)
        if f.name == "mask":
            assert a is b
        else:
            n = getattr(neutral.context, f.name)
            assert a.shape == b.shape and torch.allclose(a - n, k * (b - n), atol=1e-5)
    assert neutral.scaled(ctx, 1.0) is ctx


def test_strength_bounds():
    assert check_strength(0) == 0.0 and check_strength(4) == 4.0
    for bad in (-0.1, 4.5):
        with pytest.raises(ValueError, match=r"style_strength must be in \[0, 4\]"):
            check_strength(bad)
        with pytest.raises(ValueError):
            Overrides(style_strength=bad)
    assert InferenceConfig.from_dict({"style_strength": 2.0}).style_strength == 2.0
    assert InferenceConfig(style_strength=2.0).to_dict() == {"int8_lstm": False, "style_strength": 2.0}
    assert InferenceConfig().to_dict() == {"int8_lstm": False}  # 1 is left out: older releases load the bundle
    assert InferenceConfig().with_overrides(style_strength=1.5).style_strength == 1.5


def _frames(engine: Engine) -> torch.Tensor:
    walk = synthetic_walk(frames=160)
    style, _ = engine.encode_style(walk.window(20, 140))
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, deterministic=True)
    batch = CharacterBatch(engine)
    batch.add(ch)
    return torch.stack([batch.step().rotations[0] for _ in range(20)])


def test_the_engine_runs_styles_at_its_strength():
    bundle = Bundle.load(DEFAULT_BUNDLE)
    plain = Engine(bundle, threads=1)
    assert plain.inference.style_strength == 1.0
    one = _frames(Engine(bundle, threads=1, overrides=Overrides(style_strength=1.0)))
    assert torch.equal(one, _frames(plain))  # strength 1: the contexts as encoded, the same frames
    strong = _frames(Engine(bundle, threads=1, overrides=Overrides(style_strength=2.0)))
    assert (strong - one).abs().max() > 1e-2
    bare = Bundle.load(DEFAULT_BUNDLE, styles=False)
    with pytest.raises(ValueError, match="needs built-in styles"):
        Engine(bare, threads=1, overrides=Overrides(style_strength=2.0))
    Engine(bare, threads=1)  # strength 1 needs no neutral style


def test_a_character_runs_at_its_own_strength():
    from model.inference.errors import EngineError, NoNeutralStyle

    bundle = Bundle.load(DEFAULT_BUNDLE)
    engine = Engine(bundle, threads=1)
    walk = synthetic_walk(frames=160)
    style, _ = engine.encode_style(walk.window(20, 140))

    def run(strength: float | None) -> torch.Tensor:
        ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, deterministic=True,
                            controls={"style_strength": strength})
        return engine.generate([ch])[0][0]

    assert torch.equal(run(None), run(1.0))
    strong = run(2.0)
    assert torch.equal(strong, _frames(Engine(bundle, threads=1, overrides=Overrides(style_strength=2.0))))
    with pytest.raises(EngineError, match="style_strength must be in"):
        run(5.0)
    bare = Engine(Bundle.load(DEFAULT_BUNDLE, styles=False), threads=1)
    bare_style, _ = bare.encode_style(walk.window(20, 140))
    with pytest.raises(NoNeutralStyle, match="send 1 or leave it out"):
        bare.prepare(walk.window(0, 10), walk.window(40, 42), 20, bare_style, controls={"style_strength": 1.5})


@pytest.mark.parametrize("source", ["matching", "hybrid"])
def test_a_source_that_plays_capture_refuses_a_strength_and_runs_at_one(source: str):
    """Style strength moves the network's codes: another source's style contexts have no neutral style, so a strength
    other than 1 is refused with the reason, where it once failed inside the batch."""
    from model.inference.errors import NoNeutralStyle

    engine = Engine(Bundle.load(DEFAULT_BUNDLE), threads=1, source=source)
    walk = synthetic_walk(frames=160)
    style, _ = engine.encode_style(walk.window(20, 140))

    def prepare(strength: float):
        return engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, deterministic=True,
                              controls={"style_strength": strength})

    with pytest.raises(NoNeutralStyle, match=f"runs the {source} source"):
        prepare(1.5)
    rotations, _ = engine.generate([prepare(1.0)])[0]
    assert rotations.shape[0] == 20

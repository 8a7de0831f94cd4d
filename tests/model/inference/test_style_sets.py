"""A style from several clips (model/inference/style_sets.py) at random weights: one clip is today's style bit for
bit, several give one context over all their steps, order and repetition do not change it, errors name the clip."""

from __future__ import annotations

from dataclasses import fields

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.inference.errors import SkeletonMismatch, TooFewFrames, TooManyFrames
from model.inference.style_sets import MAX_STYLE_CLIPS, StyleClipCount, encode_style_set, style_set_context
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from model.nets.sampler import SamplerConfig, StyleContext

J = 21


def _engine() -> Engine:
    from model.nets.manifold import ManifoldConfig

    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Engine(Bundle.create(synthetic_skeleton(), cfg, man, seed=1))


@pytest.fixture()
def engine() -> Engine:
    return _engine()  # a fresh style cache each test: what is cached is part of what is tested


def _clips() -> list[Clip]:
    return [synthetic_walk(frames=60, turn_deg_s=20.0), synthetic_walk(frames=90, cadence_hz=1.3),
            synthetic_walk(frames=45, stride_deg=40.0, turn_deg_s=-30.0)]


def _same(a: StyleContext, b: StyleContext) -> bool:
    return all(torch.equal(getattr(a, f.name), getattr(b, f.name)) for f in fields(StyleContext))


def test_one_clip_is_todays_style_bit_for_bit(engine):
    clip = _clips()[0]
    alone, _ = _engine().encode_style(clip, "walk")
    as_set, cached = encode_style_set(engine, [clip], "walk")
    assert not cached and as_set.style_id == alone.style_id and as_set.clips == 1
    assert as_set.frames == alone.frames and as_set.nbytes == alone.nbytes and _same(as_set.context, alone.context)


def test_several_clips_give_one_context_over_all_their_steps(engine):
    clips = _clips()
    style, cached = encode_style_set(engine, clips, "three")
    assert not cached and style.clips == 3 and style.frames == 60 + 90 + 45
    singles = [_engine().encode_style(c)[0] for c in clips]
    steps = [s.context.mask.shape[1] for s in singles]
    assert style.context.mask.shape == (1, sum(steps)) and bool(style.context.mask.all())
    # Its real size: every clip's keys, values and mask, one set of FiLM scales and shifts.
    film = sum(getattr(style.context, n).nbytes for n in ("gamma1", "beta1", "gamma2", "beta2"))
    assert style.nbytes == style.context.nbytes == sum(s.nbytes for s in singles) - 2 * film
    # The values are each clip's own, joined in the order of the clips' ids; FiLM reads the mean over all steps.
    code = torch.cat([engine.style_code(engine.style_clip(clips[i])) for i in
                      sorted(range(3), key=lambda i: singles[i].style_id)], dim=1)
    with torch.inference_mode():
        expect = engine.net.style_context(code)
    assert _same(style.context, expect)
    joined = torch.cat([s.context.values1 for s in sorted(singles, key=lambda s: s.style_id)], dim=1)
    assert torch.equal(style.context.values1, joined)
    assert style.style_id not in {s.style_id for s in singles}


def test_order_does_not_matter_and_a_second_encoding_is_cached(engine):
    clips = _clips()
    first, _ = encode_style_set(engine, clips)
    again, cached = encode_style_set(engine, clips[::-1])
    assert cached and again is first
    fresh, cached = encode_style_set(_engine(), [clips[1], clips[2], clips[0]])  # another replica, another order
    assert not cached and fresh.style_id == first.style_id and _same(fresh.context, first.context)
    assert style_set_context(engine, clips[::-1])[0] == first.style_id
    other, _ = encode_style_set(engine, clips[:2])
    assert other.style_id != first.style_id


def test_outputs_are_deterministic(engine, walk):
    style, _ = encode_style_set(engine, _clips())
    runs = []
    for _ in range(2):
        ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, seed=3)
        runs.append(engine.generate([ch])[0])
    assert torch.equal(runs[0][0], runs[1][0]) and torch.equal(runs[0][1], runs[1][1])
    one, _ = engine.encode_style(_clips()[0])
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, one, seed=3)
    assert not torch.equal(engine.generate([ch])[0][0], runs[0][0])  # the other clips' steps are read


def test_counts_and_bad_clips_are_refused_naming_the_clip(engine):
    clips = _clips()
    with pytest.raises(StyleClipCount, match="1 to 5 clips; got 0"):
        encode_style_set(engine, [])
    with pytest.raises(StyleClipCount, match="got 6"):
        encode_style_set(engine, [clips[0]] * (MAX_STYLE_CLIPS + 1))
    short = synthetic_walk(frames=8)
    with pytest.raises(TooFewFrames, match="style clip 1: a style clip needs 16 to 240 frames"):
        encode_style_set(engine, [clips[0], short])
    with pytest.raises(TooManyFrames, match="style clip 2:"):
        encode_style_set(engine, [clips[0], clips[1], synthetic_walk(frames=300)])
    sk = clips[0].skeleton
    renamed = Skeleton.build(["Pelvis" if n == "Spine" else n for n in sk.names], list(sk.parents),
                             [list(o) for o in sk.offsets], profile="bandai-namco", end_sites=sk.end_sites)
    lacking = Clip(renamed, clips[0].rotations, clips[0].root_positions, clips[0].fps)
    with pytest.raises(SkeletonMismatch, match="style clip 1: .*Spine"):
        encode_style_set(engine, [clips[0], lacking])
    assert len(engine.styles) == 0  # nothing refused was cached

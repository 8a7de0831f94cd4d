"""The inference engine at random weights: requests, determinism, batching, retargeting, styles."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from model.data.synthetic import synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.inference.engine import CharacterBatch, Engine
from model.inference.errors import EngineError, SkeletonMismatch, TooFewFrames, TooManyFrames
from model.inference.overrides import Overrides
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig, SamplerState

J = 21


@pytest.fixture(scope="module")
def engine() -> Engine:
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Engine(Bundle.create(synthetic_skeleton(), cfg, man, seed=1))


def _run(engine, walk, frames=20, seed=5, deterministic=False, style_clip=None):
    style, _ = engine.encode_style(style_clip or walk.window(30, 150))
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), frames, style, seed=seed, deterministic=deterministic)
    return engine.generate([ch])[0]


def test_generates_the_requested_frames(engine, walk):
    rot, root = _run(engine, walk, frames=17)
    assert rot.shape == (17, J, 4) and root.shape == (17, 3)
    assert torch.allclose(rot.norm(dim=-1), torch.ones(17, J), atol=1e-4)


def test_same_seed_same_frames_and_noise_matters(engine, walk):
    a = _run(engine, walk, seed=5)
    b = _run(engine, walk, seed=5)
    c = _run(engine, walk, seed=6)
    d1 = _run(engine, walk, deterministic=True, seed=1)
    d2 = _run(engine, walk, deterministic=True, seed=2)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[0], c[0])
    assert torch.equal(d1[0], d2[0])


def test_batch_gives_what_one_at_a_time_gives(engine, walk):
    style, _ = engine.encode_style(walk.window(30, 150))
    chars = [engine.prepare(walk.window(i, i + 10), walk.window(i + 30, i + 32), 15 + i, style, seed=i) for i in range(6)]
    together = engine.generate(chars)
    for i, (rot, root) in enumerate(together):
        ch = engine.prepare(walk.window(i, i + 10), walk.window(i + 30, i + 32), 15 + i, style, seed=i)
        alone = engine.generate([ch])[0]
        assert rot.shape[0] == 15 + i
        assert torch.allclose(rot, alone[0], atol=1e-4) and torch.allclose(root, alone[1], atol=1e-3)


def test_output_is_in_the_callers_frame(engine, walk):
    """Moving and turning the whole request moves and turns the answer the same way."""
    rot, root = _run(engine, walk, deterministic=True)
    shift = torch.tensor([100.0, 0.0, -50.0])
    moved = Clip(walk.skeleton, walk.rotations, walk.root_positions + shift, walk.fps)
    rot2, root2 = _run(engine, moved, deterministic=True, style_clip=walk.window(30, 150))
    assert torch.allclose(root2, root + shift, atol=1e-2)
    assert torch.allclose(rot2, rot, atol=1e-4)


def test_style_cache(engine, walk):
    clip = walk.window(10, 70)
    a, cached_a = engine.encode_style(clip)
    b, cached_b = engine.encode_style(clip)
    assert a.style_id == b.style_id and cached_b and a.style_id.startswith("sty_")
    other, _ = engine.encode_style(walk.window(11, 71))
    assert other.style_id != a.style_id


def test_bad_requests(engine, walk):
    style, _ = engine.encode_style(walk.window(30, 150))
    with pytest.raises(TooFewFrames, match="context needs at least 10 frames"):
        engine.prepare(walk.window(0, 5), walk.window(40, 42), 10, style)
    with pytest.raises(TooManyFrames, match=f"between 1 and {engine.max_frames}"):
        engine.prepare(walk.window(0, 10), walk.window(40, 42), engine.max_frames + 1, style)
    with pytest.raises(TooFewFrames, match="a style clip needs"):
        engine.encode_style(walk.window(0, 5))
    with pytest.raises(TooManyFrames, match="a style clip needs"):
        engine.encode_style(synthetic_walk(frames=241))
    with pytest.raises(EngineError, match="between 1 and") as err:
        engine.prepare(walk.window(0, 10), walk.window(40, 42), 0, style)
    assert not isinstance(err.value, (TooFewFrames, TooManyFrames))  # a length out of range, neither of those
    sk = walk.skeleton
    keep = [i for i, n in enumerate(sk.names) if n != "Toes_R"]
    small = Skeleton(names=tuple(sk.names[i] for i in keep), parents=tuple(keep.index(sk.parents[i]) if i else -1 for i in keep),
                     offsets=tuple(sk.offsets[i] for i in keep), roles=replace(sk.roles, mirror=tuple(range(len(keep)))))
    clip = Clip(small, walk.rotations[:, keep], walk.root_positions, walk.fps)
    with pytest.raises(SkeletonMismatch, match="Toes_R"):
        engine.prepare(clip.window(0, 10), walk.window(40, 42), 10, style)


def test_context_is_resampled(engine, walk):
    fast = walk.resample(60.0)
    style, _ = engine.encode_style(walk.window(30, 150))
    ch = engine.prepare(fast.window(0, 40), walk.window(40, 42), 12, style, deterministic=True)
    rot, _ = engine.generate([ch])[0]
    assert rot.shape[0] == 12


def _play(engine, walk, frames: int, style, change=None, at: int = 0) -> list:
    """Step one deterministic character of ``frames`` frames (from the walk's frames 0-10 to 40-42) in a batch of its
    own to its end, calling ``change(character, batch)`` once it has played ``at`` frames: each step's output."""
    batch = CharacterBatch(engine)
    ch = engine.prepare(walk.window(0, 10), walk.window(40, 42), frames, style, deterministic=True)
    batch.add(ch)
    outs = []
    while not ch.done:
        outs.append(batch.step())
        if change is not None and ch.seq == at:
            change(ch, batch)
    batch.drop_finished()
    assert len(batch) == 0
    return outs


def test_retarget_changes_arrival(engine, walk):
    style, _ = engine.encode_style(walk.window(30, 150))
    far = Clip(walk.skeleton, walk.rotations[40:42], walk.root_positions[40:42] + torch.tensor([300.0, 0, 0]), walk.fps)
    plain, moved = (torch.stack([out.root_positions[0] for out in _play(engine, walk, 30, style, change, at=10)])
                    for change in (None, lambda ch, batch: engine.retarget(ch, batch, target=far, frames=15)))
    assert plain.shape[0] == 30 and moved.shape[0] == 25
    assert torch.allclose(plain[:10], moved[:10])
    assert not torch.allclose(plain[10:25], moved[10:25])


def test_a_batch_shows_its_stacked_rows_as_the_next_step_reads_them(engine, walk):
    style, _ = engine.encode_style(walk.window(30, 150))
    batch = CharacterBatch(engine)
    with pytest.raises(ValueError, match="no live characters"):
        batch.stacked()
    for seed in (1, 2):
        batch.add(engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style, seed=seed))
    state, ctx, yaw, origin, memory = batch.stacked()  # the two waiting characters joined
    assert isinstance(state, SamplerState)
    assert state.h.shape[0] == 2 and ctx.mask.shape[0] == 2 and yaw.shape == (2,) and origin.shape == (2, 3)
    assert set(memory) == set(engine.output_fn.fn.keys) and all(v.shape[0] == 2 for v in memory.values())
    batch.step()
    assert batch.stacked()[0] is not state  # a step moves the rows on


def test_style_switch_mid_motion(engine, walk):
    a, _ = engine.encode_style(walk.window(30, 150))
    b, _ = engine.encode_style(synthetic_walk(frames=60, cadence_hz=1.6, stride_deg=40.0))
    outs = [torch.stack([out.rotations[0] for out in _play(engine, walk, 20, a, change, at=5)])
            for change in (None, lambda ch, batch: batch.set_style(ch, b))]
    assert torch.allclose(outs[0][:5], outs[1][:5])
    assert not torch.allclose(outs[0][6:], outs[1][6:])


def test_exact_arrival_lands_on_the_target(engine, walk):
    from tests.model.motion.rotation_angle import quat_angle

    style, _ = engine.encode_style(walk.window(30, 150))
    target = walk.window(40, 42)
    plain = engine.generate([engine.prepare(walk.window(0, 10), target, 20, style, deterministic=True)])[0]
    exact = engine.generate([engine.prepare(walk.window(0, 10), target, 20, style, deterministic=True, exact_arrival=True)])[0]
    assert quat_angle(exact[0][-1], target.rotations[-1]).max() < 1e-3
    assert torch.allclose(exact[1][-1], target.root_positions[-1], atol=1e-3)
    assert not torch.allclose(plain[1][-1], target.root_positions[-1], atol=1e-1)  # random weights miss it
    assert torch.allclose(exact[0][:5], plain[0][:5])  # frames before the window are untouched


def test_traced_step_matches_eager(walk):
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man, seed=2)
    results = []
    for compiled in (False, True):
        eng = Engine(bundle, compiled=compiled, overrides=Overrides(foot_lock=True, floor=True, steering=6))
        assert eng.pipeline.step("floor_contact") is not None and eng.output.steering.on
        short, _ = eng.encode_style(walk.window(0, 40))
        long, _ = eng.encode_style(walk.window(10, 150))
        # Traced at batch 1 with one style length, then run at batch 3 with mixed lengths.
        first = eng.generate([eng.prepare(walk.window(0, 10), walk.window(40, 42), 8, short, seed=1)])
        chars = [eng.prepare(walk.window(i, i + 10), walk.window(40, 42), 12, s, seed=i)
                 for i, s in enumerate((short, long, short))]
        results.append((first, eng.generate(chars)))
        if compiled:
            assert not eng.step_fn.eager and eng.step_fn._graph is not None
            # The frame's way out (world space, filter, floor contact, foot lock) too.
            assert not eng.output_fn.eager and eng.output_fn._graph is not None and eng.pipeline.step("foot_lock") is not None
        else:
            assert eng.output_fn._graph is None and eng.pipeline.step("foot_lock") is not None
    (e1, e3), (c1, c3) = results
    for a, b in zip(e1 + e3, c1 + c3):
        assert torch.allclose(a[0], b[0], atol=1e-4) and torch.allclose(a[1], b[1], atol=1e-3)


def test_a_failed_trace_falls_back_to_eager_and_says_why(walk, monkeypatch, caplog):
    import model.inference.traced_step as traced_step

    def refuse(*args, **kwargs):
        raise RuntimeError("no tracing here")

    monkeypatch.setattr(traced_step.torch.jit, "trace", refuse)
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    bundle = Bundle.create(synthetic_skeleton(), cfg, man, seed=2)
    eng = Engine(bundle, compiled=True, overrides=Overrides(foot_lock=True))
    assert not eng.step_fn.eager  # wanted traced, not tried yet
    with caplog.at_level("WARNING"):
        rot, root = _run(eng, walk, frames=6)
    assert rot.shape[0] == 6 and torch.isfinite(rot).all() and torch.isfinite(root).all()
    for fn in (eng.step_fn, eng.output_fn):
        assert fn.traced and fn.trace_failed and fn.eager and fn._graph is None
    assert "no tracing here" in caplog.text
    eager = Engine(bundle, compiled=False, overrides=Overrides(foot_lock=True))
    e_rot, e_root = _run(eager, walk, frames=6)
    assert torch.equal(rot, e_rot) and torch.equal(root, e_root)
    assert eager.step_fn.eager and not eager.step_fn.trace_failed

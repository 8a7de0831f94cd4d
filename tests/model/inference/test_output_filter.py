"""The engine's causal output filter: the blend itself, its fade at arrival, and its place in the engine."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import synthetic_skeleton
from model.inference.bundle import Bundle
from model.inference.engine import CharacterBatch, Engine
from model.inference.output.settings import OutputConfig
from model.inference.output.smoothing import smooth_frame, smoothing_weight
from model.inference.overrides import Overrides
from model.motion.clip import Clip
from model.motion.rotations import quat_normalize
from model.nets.manifold import ManifoldConfig
from model.nets.sampler import SamplerConfig

J = 21


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    cfg = SamplerConfig(joints=J, phases=4, latent=8, width=32, rnn=32, head=32, style_channels=32, max_transition=40)
    man = ManifoldConfig(joints=J, phases=4, latent=8, experts=2, hidden=32, gate_hidden=16, encoder_hidden=32)
    return Bundle.create(synthetic_skeleton(), cfg, man, seed=3)


def _random_quats(*shape: int, seed: int = 0) -> torch.Tensor:
    return quat_normalize(torch.randn(*shape, 4, generator=torch.Generator().manual_seed(seed)))


def test_zero_weight_is_identity_and_one_is_the_previous_frame():
    rot, prev = _random_quats(3, J, seed=1), _random_quats(3, J, seed=2)
    root, proot = torch.randn(3, 3), torch.randn(3, 3)
    r0, p0 = smooth_frame(rot, root, prev, proot, torch.zeros(3))
    assert torch.allclose(r0, rot, atol=1e-6) and torch.equal(p0, root)
    r1, p1 = smooth_frame(rot, root, prev, proot, torch.ones(3))
    same = torch.minimum((r1 - prev).abs().amax(-1), (r1 + prev).abs().amax(-1))  # q and -q are one rotation
    assert same.max() < 1e-6 and torch.allclose(p1, proot)


def test_blend_takes_the_short_way_whatever_the_sign():
    rot, prev = _random_quats(4, J, seed=3), _random_quats(4, J, seed=4)
    w = torch.full((4,), 0.4)
    a, _ = smooth_frame(rot, torch.zeros(4, 3), prev, torch.zeros(4, 3), w)
    b, _ = smooth_frame(rot, torch.zeros(4, 3), -prev, torch.zeros(4, 3), w)
    assert torch.allclose(a, b, atol=1e-6)
    # Halfway-ish between two rotations: never further from either than they are from each other.
    def ang(x, y):
        return 2 * torch.acos((x * y).sum(-1).abs().clamp(max=1.0))

    assert (ang(a, rot) <= ang(rot, prev) + 1e-4).all() and (ang(a, prev) <= ang(rot, prev) + 1e-4).all()


def test_weight_fades_to_zero_on_the_arrival_frame():
    w = smoothing_weight(0.3, torch.tensor([0, 1, 4, 5, 30]), fade=5)
    assert torch.allclose(w, torch.tensor([0.0, 0.06, 0.24, 0.3, 0.3]))
    assert torch.allclose(smoothing_weight(0.3, torch.tensor([0, 7]), fade=0), torch.tensor([0.3, 0.3]))


def test_strength_is_validated(bundle):
    with pytest.raises(ValueError, match=r"smoothing must be in \[0, 1\)"):
        OutputConfig(smoothing=1.0)
    with pytest.raises(ValueError, match="smoothing"):
        Engine(bundle, overrides=Overrides(smoothing=-0.1))


def _generate(engine: Engine, walk: Clip, frames: int = 20):
    style, _ = engine.encode_style(walk.window(30, 150))
    return engine.generate([engine.prepare(walk.window(0, 10), walk.window(40, 42), frames, style, deterministic=True)])[0]


def test_engine_filters_its_own_frames_causally(bundle, walk):
    """Filtered frames are the raw ones run through the filter from the last context frame: the
    network's state never sees the filter, and the arrival frame is the network's own."""
    raw = _generate(Engine(bundle, overrides=Overrides(smoothing=0.0)), walk)
    smoothed = _generate(Engine(bundle, overrides=Overrides(smoothing=0.5)), walk)
    assert Engine(bundle).output.smoothing == bundle.output.smoothing == 0.0
    prev_rot, prev_root = quat_normalize(walk.rotations[9]), walk.root_positions[9]
    n = raw[0].shape[0]
    for t in range(n):
        w = smoothing_weight(0.5, torch.tensor([n - 1 - t]))
        prev_rot, prev_root = smooth_frame(raw[0][t : t + 1], raw[1][t : t + 1], prev_rot.view(1, J, 4),
                                           prev_root.view(1, 3), w)
        prev_rot, prev_root = prev_rot[0], prev_root[0]
        assert torch.allclose(smoothed[0][t], prev_rot, atol=1e-5) and torch.allclose(smoothed[1][t], prev_root, atol=1e-4)
    assert torch.allclose(smoothed[0][-1], raw[0][-1], atol=1e-6) and torch.allclose(smoothed[1][-1], raw[1][-1])
    assert not torch.allclose(smoothed[1][:5], raw[1][:5], atol=1e-3)


def test_foot_lock_in_the_engine_keeps_the_arrival_frame(bundle, walk):
    plain = _generate(Engine(bundle, overrides=Overrides(smoothing=0.0, foot_lock=False)), walk, frames=30)
    locked = _generate(Engine(bundle, overrides=Overrides(smoothing=0.0, foot_lock=True)), walk, frames=30)
    assert torch.equal(locked[1], plain[1])  # roots are never moved
    assert torch.allclose(locked[0][-1], plain[0][-1], atol=1e-6)


def test_output_memory_survives_detach_and_batch_changes(bundle, walk):
    """The filter's and the foot lock's per-character memory follow a character out of a batch and back."""
    engine = Engine(bundle, overrides=Overrides(smoothing=0.4, foot_lock=True))
    style, _ = engine.encode_style(walk.window(30, 150))

    def prepare(i: int):
        return engine.prepare(walk.window(i, i + 10), walk.window(i + 30, i + 32), 18, style, deterministic=True)

    alone = [engine.generate([prepare(i)])[0] for i in range(3)]
    chars = [prepare(i) for i in range(3)]
    batch = CharacterBatch(engine)
    for ch in chars:
        batch.add(ch)
    frames: dict[int, list] = {i: [] for i in range(3)}
    step = 0
    while len(batch):
        if step == 4:
            batch.detach(chars[1])  # paused for three frames while the others go on
        if step == 7:
            batch.add(chars[1])
        out = batch.step()
        for k, ch in enumerate(out.characters):
            frames[chars.index(ch)].append((out.rotations[k], out.root_positions[k]))
        batch.drop_finished()
        step += 1
    for i in range(3):
        rot = torch.stack([f[0] for f in frames[i]])
        root = torch.stack([f[1] for f in frames[i]])
        assert torch.allclose(rot, alone[i][0], atol=1e-4) and torch.allclose(root, alone[i][1], atol=1e-3)


def test_output_settings_are_saved_with_the_bundle(bundle, tmp_path):
    import json
    from dataclasses import replace

    from model.inference.bundle import BundleError

    b = replace(bundle, output=OutputConfig(smoothing=0.3, foot_lock=True))
    b.save(tmp_path / "b")
    assert Bundle.load(tmp_path / "b").output == OutputConfig(0.3, True)
    assert Engine(Bundle.load(tmp_path / "b")).pipeline.step("foot_lock") is not None
    cfg = json.loads((tmp_path / "b" / "config.json").read_text())
    cfg["output"] = {"smoothing": 2.0}
    (tmp_path / "b" / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(BundleError, match="output"):
        Bundle.load(tmp_path / "b")
    del cfg["output"]  # a bundle from before the setting existed: frames as the network makes them
    (tmp_path / "b" / "config.json").write_text(json.dumps(cfg))
    assert Bundle.load(tmp_path / "b").output == OutputConfig()


def test_root_has_its_own_strength_and_overrides_combine(bundle):
    rot, prev = _random_quats(2, J, seed=5), _random_quats(2, J, seed=6)
    root, proot = torch.zeros(2, 3), torch.ones(2, 3)
    r, p = smooth_frame(rot, root, prev, proot, torch.full((2,), 0.5), torch.full((2,), 0.2))
    assert torch.allclose(p, torch.full((2, 3), 0.2))
    assert torch.allclose(r, smooth_frame(rot, root, prev, proot, torch.full((2,), 0.5))[0])
    with pytest.raises(ValueError, match=r"root_smoothing must be in \[0, 1\)"):
        OutputConfig(smoothing=0.3, root_smoothing=1.0)
    from dataclasses import replace

    b = replace(bundle, output=OutputConfig(smoothing=0.5, root_smoothing=0.2))
    assert Engine(b).output.root_strength == 0.2
    assert Engine(b, overrides=Overrides(smoothing=0.0)).output == OutputConfig(0.0)  # one override turns the whole filter off
    assert Engine(b, overrides=Overrides(root_smoothing=0.1)).output == OutputConfig(0.5, root_smoothing=0.1)
    assert not Engine(b, overrides=Overrides(smoothing=0.0)).output.smooths

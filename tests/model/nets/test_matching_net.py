"""The matching source: the engine plays windows of a bundle's motion database onto a character's pose and target,
traced as eager, keeps to the style a clip looks like, plans again on a retarget, and says what is missing."""

from __future__ import annotations

import pytest
import torch

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_skeleton
from model.inference.bundle import Bundle
from model.inference.character_batch import CharacterBatch
from model.inference.engine import Engine
from model.inference.errors import EngineError
from model.nets.matching_net import MatchingNet
from tests.model.nets.walk_database import style_walk, walk_bundle


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    return walk_bundle()


@pytest.fixture(scope="module")
def engine(bundle: Bundle) -> Engine:
    return Engine(bundle, source="matching")


def test_a_clip_plays_the_database_style_it_looks_like(engine: Engine) -> None:
    assert isinstance(engine.net, MatchingNet)
    for style in ("brisk", "slow"):
        encoded, _ = engine.encode_style(style_walk(style, frames=120).window(10, 100))
        assert engine.net.style_name(encoded.context) == [style]


@pytest.mark.parametrize("gap", [10, 40])
def test_a_transition_plays_its_style_s_capture_and_arrives(engine: Engine, gap: int) -> None:
    walk = style_walk("slow", frames=120)
    style, _ = engine.encode_style(style_walk("slow", frames=120).window(10, 100))
    target = walk.window(10 + gap - 2, 10 + gap)
    rot, root = engine.generate([engine.prepare(walk.window(0, 10), target, gap, style, deterministic=True)])[0]
    assert rot.shape == (gap, engine.skeleton.num_joints, 4)
    miss = (root[-1, [0, 2]] - walk.root_positions[10 + gap - 1, [0, 2]]).norm()
    assert float(miss) < 2.0, f"ended {float(miss):.1f} cm from the target"
    speed = (root[1:, [0, 2]] - root[:-1, [0, 2]]).norm(dim=-1).mean() * 30.0
    assert float(speed) == pytest.approx(SYNTHETIC_STYLES["slow"][0], rel=0.15)  # the slow walk's pace, not the brisk one


def test_the_traced_step_gives_the_eager_frames(bundle: Bundle, engine: Engine) -> None:
    eager = Engine(bundle, source="matching", compiled=False)
    walk = style_walk("brisk", frames=120)
    outs = []
    for e in (engine, eager):
        style, _ = e.encode_style(walk.window(10, 100))
        outs.append(e.generate([e.prepare(walk.window(0, 10), walk.window(38, 40), 30, style, deterministic=True)])[0])
    assert torch.allclose(outs[0][0], outs[1][0], atol=1e-5) and torch.allclose(outs[0][1], outs[1][1], atol=1e-4)


def test_a_retarget_plans_again_from_where_it_stands(engine: Engine) -> None:
    walk = style_walk("brisk", frames=160)
    style, _ = engine.encode_style(walk.window(10, 100))
    ch = engine.prepare(walk.window(0, 10), walk.window(48, 50), 40, style, deterministic=True)
    batch = CharacterBatch(engine)
    batch.add(ch)
    roots = [batch.step().root_positions[0] for _ in range(10)]
    engine.retarget(ch, batch, target=walk.window(78, 80), frames=50)
    while not ch.done:
        roots.append(batch.step().root_positions[0])
    assert len(roots) == 60
    miss = (roots[-1][[0, 2]] - walk.root_positions[79, [0, 2]]).norm()
    assert float(miss) < 3.0, f"ended {float(miss):.1f} cm from the new target"


def test_a_bundle_without_a_database_or_an_unknown_source_is_refused(bundle: Bundle) -> None:
    bare = Bundle.create(synthetic_skeleton(), seed=0)
    with pytest.raises(EngineError, match="rsmt bundle database"):
        Engine(bare, source="matching")
    with pytest.raises(EngineError, match="unknown motion source"):
        Engine(bundle, source="capture")

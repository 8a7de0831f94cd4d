"""A style clip's own frames are searched first by the matching and hybrid sources: a transition of motion the
database lacks plays the clip's window (so it follows the clip's motion exactly), every clip of a style set gives its
frames, and a request the database covers better plays the database's window as before."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from model.inference.bundle import Bundle
from model.inference.character import EncodedStyle
from model.inference.engine import Engine
from model.inference.style_sets import encode_style_set
from model.motion.clip import Clip
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize
from model.nets.matching_net import CLIP_COST_FACTOR
from tests.model.nets.walk_database import style_walk, walk_bundle

Tensor = torch.Tensor


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    return walk_bundle()  # brisk and slow walks, straight and turning 25 degrees a second


def _positions(engine: Engine, rot: Tensor, root: Tensor) -> Tensor:
    sk = engine.skeleton
    return forward_kinematics(quat_normalize(rot), root, sk.offsets_tensor(), sk.parents)[0]


def _without_clip_frames(style: EncodedStyle) -> EncodedStyle:
    ctx = style.context
    return replace(style, context=replace(ctx, clip_segment=torch.zeros_like(ctx.clip_segment)))


def _error_cm(engine: Engine, walk: Clip, style: EncodedStyle, start: int, gap: int) -> float:
    """Mean joint distance (cm) of the transition from ``walk``'s frames ``start-10..start`` to its frame
    ``start+gap-1`` to ``walk``'s own frames in between."""
    truth = _positions(engine, walk.rotations, walk.root_positions)
    character = engine.prepare(walk.window(start - 10, start), walk.window(start + gap - 2, start + gap), gap, style,
                               deterministic=True)
    rot, root = engine.generate([character])[0]
    return float((_positions(engine, rot, root) - truth[start:start + gap]).norm(dim=-1).mean())


@pytest.mark.parametrize("source", ["matching", "hybrid"])
@pytest.mark.parametrize("gap", [10, 45])
def test_motion_the_database_lacks_plays_the_style_clip_s_own_frames(bundle: Bundle, source: str, gap: int) -> None:
    engine = Engine(bundle, source=source)
    walk = style_walk("bouncy", frames=160, turn=60.0)  # a pace, cadence and turn no database walk has
    style, _ = engine.encode_style(walk.window(10, 120))
    with_clip = _error_cm(engine, walk, style, 30, gap)
    database_only = _error_cm(engine, walk, _without_clip_frames(style), 30, gap)
    print(f"{source} gap {gap}: {with_clip:.5f} cm from the clip's own motion with its frames, "
          f"{database_only:.2f} cm from the database alone")
    assert with_clip < 0.01  # the clip's window, played from the same pose onto its own end: the clip itself
    assert database_only > 1.0


def test_every_clip_of_a_style_set_gives_its_frames(bundle: Bundle) -> None:
    engine = Engine(bundle, source="matching")
    bouncy = style_walk("bouncy", frames=160, turn=-60.0)
    style, _ = encode_style_set(engine, [style_walk("brisk", frames=120).window(10, 100), bouncy.window(10, 120)])
    assert style.clips == 2 and int(style.context.clip_segment.max()) == 2  # one segment per clip
    assert _error_cm(engine, bouncy, style, 40, 30) < 0.01


def test_a_request_the_database_covers_better_plays_the_database_as_before(bundle: Bundle) -> None:
    engine = Engine(bundle, source="matching")
    walk = style_walk("brisk", turn=25.0)  # one of the database's own walks
    # A brisk walk turning the other way, fast: its windows match this request far worse than the database's.
    style, _ = engine.encode_style(style_walk("brisk", frames=120, turn=-180.0).window(10, 100))
    frames = []
    for s in (style, _without_clip_frames(style)):
        character = engine.prepare(walk.window(30, 40), walk.window(68, 70), 30, s, deterministic=True)
        frames.append(engine.generate([character])[0])
    assert torch.equal(frames[0][0], frames[1][0]) and torch.equal(frames[0][1], frames[1][1])


def test_a_clip_too_short_for_the_transition_leaves_it_to_the_database(bundle: Bundle) -> None:
    engine = Engine(bundle, source="matching")
    walk = style_walk("bouncy", frames=160, turn=60.0)
    style, _ = engine.encode_style(walk.window(20, 50))  # 29 frames rebuilt: no window of 46 frames
    with_clip = _error_cm(engine, walk, style, 30, 45)
    assert with_clip == pytest.approx(_error_cm(engine, walk, _without_clip_frames(style), 30, 45))
    assert CLIP_COST_FACTOR < 1.0  # the clip is preferred where it has a window (the test above)

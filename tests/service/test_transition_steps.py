"""A transition stepped a slice at a time (``service.transition_steps``) gives exactly the frames of
``Engine.generate``, however small the slices."""

from __future__ import annotations

import pytest
import torch

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from service.transition_steps import TransitionSteps
from tests.service.conftest import context_clip, target_clip, walk


@pytest.fixture(scope="module")
def engine(bundle_dir) -> Engine:
    return Engine(Bundle.load(bundle_dir), threads=1)


@pytest.mark.parametrize("budget_s", [0.0, 1e9])
def test_slices_give_the_frames_of_generate(engine: Engine, budget_s: float):
    style, _ = engine.encode_style(walk(40))
    rotations, roots = engine.generate([engine.prepare(context_clip(), target_clip(), 25, style, seed=3)])[0]
    steps = TransitionSteps(engine, engine.prepare(context_clip(), target_clip(), 25, style, seed=3))
    calls = 1
    while not steps.advance(budget_s):
        calls += 1
    assert calls == (25 if budget_s == 0.0 else 1)  # one frame a slice at least; all at once with time to spare
    sliced_rotations, sliced_roots = steps.frames()
    assert torch.equal(sliced_rotations, rotations) and torch.equal(sliced_roots, roots)
    assert steps.seconds > 0

"""Capture and network together: with every request covered the hybrid plays what the matching source plays, with
none it makes what the network makes, and a character it plays keeps the network's state warm beside it."""

from __future__ import annotations

import pytest
import torch

from model.inference.bundle import Bundle
from model.inference.engine import Engine
from model.nets.hybrid_net import HybridNet, HybridState
from tests.model.nets.walk_database import style_walk, walk_bundle


@pytest.fixture(scope="module")
def bundle() -> Bundle:
    return walk_bundle()


def _run(engine: Engine) -> tuple[torch.Tensor, torch.Tensor]:
    walk = style_walk("slow", frames=120)
    style, _ = engine.encode_style(walk.window(10, 100))
    return engine.generate([engine.prepare(walk.window(0, 10), walk.window(38, 40), 30, style, deterministic=True)])[0]


@pytest.mark.parametrize(("limit", "like"), [(float("inf"), "matching"), (float("-inf"), "network")])
def test_the_hybrid_plays_capture_where_it_matches_and_the_network_elsewhere(bundle: Bundle, limit: float,
                                                                             like: str) -> None:
    hybrid = Engine(bundle, source="hybrid")
    assert isinstance(hybrid.net, HybridNet)
    hybrid.net.limit = limit
    got, want = _run(hybrid), _run(Engine(bundle, source=like))
    assert torch.allclose(got[0], want[0], atol=1e-4) and torch.allclose(got[1], want[1], atol=1e-3)


def test_a_played_character_keeps_the_network_warm(bundle: Bundle) -> None:
    engine = Engine(bundle, source="hybrid")
    assert isinstance(engine.net, HybridNet)
    engine.net.limit = float("inf")  # every request played
    walk = style_walk("slow", frames=120)
    style, _ = engine.encode_style(walk.window(10, 100))
    ch = engine.prepare(walk.window(0, 10), walk.window(38, 40), 30, style, deterministic=True)
    state = engine.begin([ch])
    assert isinstance(state, HybridState) and bool(state.played.all())
    assert float(state.h.abs().sum()) > 0.0  # the sampler warmed up on the context beside the plan

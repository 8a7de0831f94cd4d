"""Fixtures shared by the model-level tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from model.data.preprocessed import MotionCache, load_motion_cache
from model.data.synthetic import synthetic_walk, write_synthetic_dataset
from model.motion.clip import Clip


@pytest.fixture(scope="module")
def walk() -> Clip:
    """A 150-frame synthetic walk that turns at 20 degrees a second: contexts, targets and style clips."""
    return synthetic_walk(frames=150, turn_deg_s=20.0)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A small synthetic BVH dataset (3 takes of each style and content, 150 frames each): its folder, and the folder
    its motion cache is kept in."""
    root = tmp_path_factory.mktemp("synthetic")
    write_synthetic_dataset(root / "data", takes_per_pair=3, frames=150)
    return root / "data", root / "cache"


@pytest.fixture(scope="module")
def cache(dataset: tuple[Path, Path]) -> MotionCache:
    """The motion cache of :func:`dataset`, loaded by one worker (in place of pytest's own ``cache`` fixture, which
    no model test uses)."""
    data, root = dataset
    return load_motion_cache(data, root=root, workers=1, progress=False)

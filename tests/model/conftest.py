"""Fixtures shared by the engine-level tests."""

from __future__ import annotations

import pytest

from model.data.synthetic import synthetic_walk
from model.motion.clip import Clip


@pytest.fixture(scope="module")
def walk() -> Clip:
    """A 150-frame synthetic walk that turns at 20 degrees a second: contexts, targets and style clips."""
    return synthetic_walk(frames=150, turn_deg_s=20.0)

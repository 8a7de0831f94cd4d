"""Synthetic walks of the built-in styles, and a fresh bundle whose motion database holds them (for the matching
and hybrid sources' tests)."""

from __future__ import annotations

from collections.abc import Sequence

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_skeleton, synthetic_walk
from model.inference.bundle import Bundle
from model.motion.clip import Clip
from model.retrieval.database import MotionDatabase


def style_walk(style: str, frames: int = 200, turn: float = 0.0) -> Clip:
    """A synthetic walk at ``style``'s pace, cadence and stride, turning ``turn`` degrees a second."""
    speed, cadence, stride = SYNTHETIC_STYLES[style]
    return synthetic_walk(frames=frames, speed_cm_s=speed, cadence_hz=cadence, stride_deg=stride, turn_deg_s=turn)


def walk_bundle(turns: Sequence[float] = (0.0, 25.0, -25.0)) -> Bundle:
    """An untrained bundle (seed 0) whose database holds a brisk and a slow walk at each of ``turns``."""
    segments = [(w.rotations, w.root_positions, style, "walk") for style in ("brisk", "slow")
                for w in (style_walk(style, turn=turn) for turn in turns)]
    made = Bundle.create(synthetic_skeleton(), seed=0)
    made.database = MotionDatabase.from_segments(made.skeleton, 30.0, segments, "synthetic walks")
    return made

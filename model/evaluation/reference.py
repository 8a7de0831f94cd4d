"""Statistics of the training split that the metrics need: L2P's position statistics and the feet's ground levels.

* :class:`~model.evaluation.metrics.PositionStats` for L2P are computed, like the reference benchmark's
  ``style100_benchmark_stat``, over the **training split** in the frame the metric is taken in:
  the training takes are cut into windows exactly as evaluation cases are (50 frames from frames
  0, 40, 80, ...), each window is put in the canonical frame of its frame 9, and the per-coordinate
  mean and std are taken over all frames of all windows.
* Ground levels for foot skate (:func:`model.evaluation.metrics.ground_levels`): per foot joint, the 5th
  percentile of its height over every frame of the training takes.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
from tqdm import tqdm

from model.data.preprocessed import MotionCache
from model.evaluation.cases import CASE_STEP, LAST_CONTEXT, SPAN
from model.evaluation.metrics import PositionStats, ground_levels
from model.motion.features import CanonicalFrame
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize

Tensor = torch.Tensor


@dataclass(frozen=True)
class ReferenceStats:
    """``positions`` for L2P and ``ground`` levels (cm) of the ``feet`` joints, with their provenance."""

    positions: PositionStats
    feet: tuple[int, ...]
    ground: Tensor
    takes: int
    windows: int

    def to_dict(self) -> dict[str, Any]:
        return {"positions": self.positions.to_dict(), "feet": list(self.feet), "ground_cm": self.ground.tolist(),
                "takes": self.takes, "windows": self.windows}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ReferenceStats:
        return cls(PositionStats.from_dict(data["positions"]), tuple(data["feet"]),
                   torch.tensor(data["ground_cm"], dtype=torch.float32), int(data.get("takes", 0)), int(data.get("windows", 0)))


def reference_stats(cache: MotionCache, takes: Sequence[int], progress: bool = False) -> ReferenceStats:
    """Position statistics and ground levels from ``takes`` (the training split); see the module docstring."""
    if not takes:
        raise ValueError("no training takes to compute the reference statistics from")
    sk0 = cache.skeleton(takes[0])
    windows, heights, count = [], [], 0
    for i in tqdm(list(takes), desc="reference statistics", unit="take", disable=not progress, leave=False,
                  file=sys.stderr):
        sk = cache.skeleton(i)
        pos, _ = forward_kinematics(quat_normalize(cache.rotations(i).float()), cache.root_positions(i).float(),
                                    sk.offsets_tensor(), sk.parents)
        heights.append(pos[:, list(sk.feet)])
        n = pos.shape[0]
        starts = list(range(0, n - SPAN + 1, CASE_STEP))
        if starts:
            w = torch.stack([pos[s:s + SPAN] for s in starts])  # [W, SPAN, J, 3]
            frame = CanonicalFrame.at_frame(w, sk, LAST_CONTEXT)
            windows.append(frame.positions_to(w))
            count += len(starts)
    if not windows:
        raise ValueError(f"no training take has the {SPAN} frames of an evaluation window")
    feet = tuple(sk0.feet)
    ground = ground_levels(list(heights), range(len(feet)))
    return ReferenceStats(PositionStats.from_positions(windows), feet, ground, len(takes), count)

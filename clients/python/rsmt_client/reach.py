"""The ``reach`` notice of a transition or a stream's ``started`` / ``retargeted`` message (docs/api-contract.md).

The server keeps a character's root within its style's capture speed, so a target farther than that speed
covers in the frames asked is not reached: the character arrives short (it does not glide there). The
notice says so before a frame is read: ``feasible`` false, with the frames the distance would take.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Reach:
    """``feasible``: whether ``distance_cm`` (root to target root, on the ground) is covered in ``frames`` at
    ``max_speed_cm_s`` (the style's capture maximum); ``reachable_cm``: what that speed covers in ``frames``;
    ``needed_frames``: the frames the distance takes at it."""

    feasible: bool
    distance_cm: float
    frames: int
    needed_frames: int
    reachable_cm: float
    max_speed_cm_s: float

    @classmethod
    def from_message(cls, data: Mapping[str, Any] | None) -> Reach | None:
        """The notice of a response body or stream message (its ``reach`` field; None where it has none)."""
        raw = None if data is None else data.get("reach")
        if not raw:
            return None
        return cls(bool(raw["feasible"]), float(raw["distance_cm"]), int(raw["frames"]), int(raw["needed_frames"]),
                   float(raw["reachable_cm"]), float(raw["max_speed_cm_s"]))

"""The ``reach`` notice of a transition or a stream's ``started`` / ``retargeted`` / ``style_changed`` message
(docs/api-contract.md).

The server keeps a character's root within its style's capture speed, so a target farther than that speed
covers in the frames asked is not reached: the character arrives short (it does not glide there). The
notice says so before a frame is read: ``feasible`` false, with the frames the distance would take. A stream's
result keeps the last notice it saw (:attr:`rsmt_client.StreamResult.reach`), so a caller can tell a character
that stopped short from one that arrived.
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

    @property
    def short_cm(self) -> float:
        """How far short of the target the character stops (0 where the target is within reach)."""
        return 0.0 if self.feasible else max(0.0, self.distance_cm - self.reachable_cm)

    @classmethod
    def from_message(cls, data: Mapping[str, Any] | None) -> Reach | None:
        """The notice of a response body or stream message (its ``reach`` field; None where it has none)."""
        raw = None if data is None else data.get("reach")
        if not raw:
            return None
        return cls(bool(raw["feasible"]), float(raw["distance_cm"]), int(raw["frames"]), int(raw["needed_frames"]),
                   float(raw["reachable_cm"]), float(raw["max_speed_cm_s"]))

"""A target given as a place and a facing (the contract's ``target_at``), instead of a pose.

    c.transition("context.bvh", TargetAt(x=120, z=300, yaw=90), 40, style_id=style)

The server picks the pose to arrive in (the context's last one, turned and moved there) and arrives exactly
there, facing that way. Anywhere a target goes (``Client.transition``, ``transition_bvh``, a stream's
``start``), a ``TargetAt`` may go instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class TargetAt:
    """Where the root arrives (``x``, ``z``: the model's units and axes, Y up) and the facing it arrives with
    (``yaw``: degrees about +Y; 0 faces +Z, 90 faces +X)."""

    x: float
    z: float
    yaw: float

    def __post_init__(self) -> None:
        if not all(math.isfinite(float(v)) for v in (self.x, self.z, self.yaw)):
            raise ValueError(f"TargetAt needs finite x, z and yaw; got {self.x}, {self.z}, {self.yaw}")

    @classmethod
    def parse(cls, text: str) -> TargetAt:
        """``"X,Z,YAW"`` (the CLI's ``--target-at``)."""
        parts = text.split(",")
        if len(parts) != 3:
            raise ValueError(f"a place and facing is X,Z,YAW (cm, cm, degrees), e.g. 120,300,90; got {text!r}")
        try:
            return cls(*(float(p) for p in parts))
        except ValueError:
            raise ValueError(f"a place and facing is three numbers X,Z,YAW, e.g. 120,300,90; got {text!r}") from None

    def payload(self) -> dict[str, Any]:
        """The contract's ``target_at`` object."""
        return {"x": float(self.x), "z": float(self.z), "yaw": float(self.yaw)}


def target_field(target: Any, cut: Callable[[dict[str, Any]], dict[str, Any]]) -> dict[str, Any]:
    """A request's target: ``{"target_at": ...}`` for a :class:`TargetAt`, else ``{"target": ...}``, the Motion
    (:func:`rsmt_client.motion.motion_payload`) through ``cut``."""
    if isinstance(target, TargetAt):
        return {"target_at": target.payload()}
    from rsmt_client.motion import motion_payload

    return {"target": cut(motion_payload(target))}

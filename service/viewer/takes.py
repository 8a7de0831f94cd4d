"""Takes for the web viewer (``/viewer``): demo takes made on request, and uploaded takes read as JSON poses.

The viewer draws poses in the browser; what it cannot do well there is read arbitrary BVH (channel
orders, extra joints, other frame rates) and map it onto the model's rig. So takes go through the
same reader and conforming as every other Motion payload (:mod:`service.motion`), and come back as
JSON poses on the model's skeleton at its fps, ready for forward kinematics and for sending back as
``context``/``target`` of ``POST /v1/transition``.

Demo takes are procedural walks on the synthetic rig (:mod:`model.data.synthetic`), generated at request
time, so no dataset file ships with the service. Their joint names are Bandai-Namco's, so they conform
to any model on that rig; a model on another rig answers ``skeleton_mismatch`` and the viewer asks
for an uploaded take instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_walk
from model.inference.errors import SkeletonMismatch
from model.motion.clip import Clip
from service.errors import ServiceError
from service.motion import motion_to_clip
from service.registry import LoadedModel
from service.viewer.schemas import ClipRequest


@dataclass(frozen=True)
class Demo:
    name: str
    kind: Literal["take", "style"]
    description: str
    make: Callable[[], Clip]


def _style_clip(style: str) -> Callable[[], Clip]:
    speed, cadence, stride = SYNTHETIC_STYLES[style]
    # 90 frames (3 s): inside every shipped model's style clip range, long enough for two gait cycles.
    return lambda: synthetic_walk(90, speed_cm_s=speed, cadence_hz=cadence, stride_deg=stride)


# Takes are long enough (8 s) to pick a context point and a target a second or two later.
DEMOS: dict[str, Demo] = {d.name: d for d in (
    Demo("walk", "take", "a straight walk, 8 s", lambda: synthetic_walk(240)),
    Demo("walk-turn-left", "take", "a walk turning left at 30 deg/s, 8 s", lambda: synthetic_walk(240, turn_deg_s=30.0)),
    Demo("walk-turn-right", "take", "a brisk walk turning right at 25 deg/s, 8 s",
         lambda: synthetic_walk(240, speed_cm_s=150.0, cadence_hz=1.1, stride_deg=30.0, turn_deg_s=-25.0)),
    *(Demo(f"style-{s}", "style", f"synthetic '{s}' gait, 3 s: a style clip to register", _style_clip(s))
      for s in SYNTHETIC_STYLES),
)}


def demo_list() -> dict[str, Any]:
    return {"demos": [{"name": d.name, "kind": d.kind, "description": d.description} for d in DEMOS.values()]}


def clip_poses(clip: Clip, name: str) -> dict[str, Any]:
    """JSON poses as float32 arrays (written by ``service.motion.dumps`` with the shortest exact text)."""
    return {
        "name": name,
        "fps": float(clip.fps),
        "frames": clip.num_frames,
        "root_positions": np.ascontiguousarray(clip.root_positions.numpy(), dtype=np.float32),
        "rotations": np.ascontiguousarray(clip.rotations.numpy(), dtype=np.float32),
    }


def demo_poses(model: LoadedModel, name: str) -> dict[str, Any]:
    """A demo take or style clip conformed to ``model``'s rig (blocking: run it on the model's threads)."""
    demo = DEMOS.get(name)
    if demo is None:
        raise ServiceError("not_found", f"no demo {name!r}; known: {', '.join(DEMOS)} (GET /v1/viewer/demos)")
    try:
        clip = model.engine.conform(demo.make(), f"demo {name!r}")
    except SkeletonMismatch as exc:
        raise ServiceError("skeleton_mismatch", f"{exc}. The demos are on the synthetic Bandai-Namco rig; this model's "
                                                "skeleton differs, so upload a BVH take of its rig instead") from exc
    return clip_poses(clip, name)


def uploaded_poses(model: LoadedModel, req: ClipRequest) -> dict[str, Any]:
    """An uploaded take read with the service's BVH reader (any channel order, frame time, extra joints)."""
    return clip_poses(motion_to_clip(req.motion, model.engine, model.limits, req.name), req.name)

"""Takes for the web viewer (``/viewer``): demo takes on the model's own rig, and uploaded takes read as JSON poses.

The viewer draws poses in the browser; what it cannot do well there is read arbitrary BVH (channel
orders, extra joints, other frame rates) and map it onto the model's rig. So takes go through the
same reader and conforming as every other Motion payload (:mod:`service.motion`), and come back as
JSON poses on the model's skeleton at its fps, ready for forward kinematics and for sending back as
``context``/``target`` of ``POST /v1/transition``.

Demo takes must be motion of the model's own rig: rotations carried over to another rig by joint name
keep each joint's world orientation, and where the two rigs' rest poses differ (a bone along +Y at rest
on one, along +X on the other) the person comes out lying on its side. So:

- a model whose bundle ships built-in styles (``BUNDLE/styles/``, captured clips on its rig) offers those
  clips as its demo takes, ``walk-NAME``; their styles are the ``builtin:NAME`` ids of ``GET /v1/model``;
- a model on the synthetic test rig (:mod:`model.data.synthetic`) gets procedural walks made at request
  time, and procedural style clips;
- any other model has no demos: the viewer asks for an uploaded take.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_skeleton, synthetic_walk
from model.inference.errors import SkeletonMismatch
from model.motion.clip import Clip
from model.motion.skeleton import Skeleton
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


# The built-in style whose walk the viewer opens with (the first take listed), when the bundle has it.
FIRST_BUILTIN = "normal"


def _fixed(clip: Clip) -> Callable[[], Clip]:
    return lambda: clip


def _on_synthetic_rig(skeleton: Skeleton) -> bool:
    rig = synthetic_skeleton()
    return (skeleton.names == rig.names and skeleton.parents == rig.parents
            and bool(np.allclose(skeleton.offsets, rig.offsets, atol=1e-3)))


def _demos(model: LoadedModel) -> dict[str, Demo]:
    styles = model.engine.bundle.styles
    if styles:
        order = sorted(styles, key=lambda n: (n != FIRST_BUILTIN, n))
        return {f"walk-{n}": Demo(f"walk-{n}", "take", f"a captured '{n}' walk, {styles[n].clip.duration_s:.0f} s "
                                                        f"(the clip of builtin:{n})", _fixed(styles[n].clip))
                for n in order}
    if _on_synthetic_rig(model.engine.skeleton):
        return DEMOS
    return {}


def demo_list(model: LoadedModel) -> dict[str, Any]:
    return {"demos": [{"name": d.name, "kind": d.kind, "description": d.description} for d in _demos(model).values()]}


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
    """A demo take or style clip on ``model``'s rig (blocking: run it on the model's threads)."""
    demos = _demos(model)
    demo = demos.get(name)
    if demo is None:
        known = ", ".join(demos) or "none for this model (its bundle has no built-in styles): upload a BVH take"
        raise ServiceError("not_found", f"no demo {name!r}; known: {known} (GET /v1/viewer/demos)")
    try:
        clip = model.engine.conform(demo.make(), f"demo {name!r}")
    except SkeletonMismatch as exc:  # cannot happen for the demos above; kept as the contract's error if it did
        raise ServiceError("skeleton_mismatch", f"{exc}; upload a BVH take of the model's rig instead") from exc
    return clip_poses(clip, name)


def uploaded_poses(model: LoadedModel, req: ClipRequest) -> dict[str, Any]:
    """An uploaded take read with the service's BVH reader (any channel order, frame time, extra joints)."""
    return clip_poses(motion_to_clip(req.motion, model.engine, model.limits, req.name), req.name)

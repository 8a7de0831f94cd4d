"""Motion payloads (BVH text or JSON poses) to clips on a model's skeleton, and generated frames back out.

Everything here is CPU work on untrusted input: callers run it off the event loop. BVH text is
parsed as text only (never treated as a path), and every limit is checked before anything grows
with the input (frame counts after resampling included).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import orjson
import torch

from model.inference.engine import Engine
from model.inference.errors import EngineError
from model.motion.bvh import BvhDocument, BvhError
from model.motion.bvh_clip import dump_clip, to_clip
from model.motion.bvh_parser import MAX_FPS, MIN_FPS  # the reader refuses a Frame Time outside them
from model.motion.clip import Clip
from model.motion.skeleton import BUILTIN_PROFILES, Skeleton, SkeletonError, SkeletonProfile, fit_names, profile_of
from model.motion.skeleton import plain_joint_name as _plain
from service.errors import ServiceError, from_engine
from service.schemas import BvhMotion, PoseMotion


@dataclass(frozen=True)
class MotionLimits:
    """What one Motion payload may hold."""

    max_frames: int = 1200
    quaternion_tolerance: float = 1e-2
    max_abs_position: float = 1e6


def motion_to_clip(motion: BvhMotion | PoseMotion | None, engine: Engine, limits: MotionLimits, what: str) -> Clip:
    """Convert a payload to a clip on ``engine``'s skeleton at its fps; errors name ``what`` and the fix. None (a
    target given as ``target_at`` that nothing placed: :mod:`service.placed_targets` does) is ``bad_motion``.

    Raises:
        ServiceError: ``bad_motion``, ``skeleton_mismatch``, ``too_few_frames`` or ``too_many_frames``.
    """
    if motion is None:
        raise ServiceError("bad_motion", f"{what}: no motion was given; send a Motion ({{\"bvh\": ...}} or JSON poses)")
    return conform_motion(parse_motion(motion, engine, limits, what), engine, what)


def parse_motion(motion: BvhMotion | PoseMotion, engine: Engine, limits: MotionLimits, what: str) -> Clip:
    """A payload as a clip on the rig it was sent on (a BVH's own; JSON poses are on the model's), not yet
    mapped onto the model's rig (:func:`conform_motion`); raises as :func:`motion_to_clip` does."""
    if isinstance(motion, BvhMotion):
        clip = _bvh_clip(motion.bvh, engine, limits, what)
    else:
        clip = _pose_clip(motion, engine.skeleton, float(motion.fps or engine.config.fps), limits, what)
    _check_resampled_length(clip, engine.config.fps, limits, what)
    return clip


def conform_motion(clip: Clip, engine: Engine, what: str) -> Clip:
    """A parsed payload (:func:`parse_motion`) on the model's rig at its fps; ``skeleton_mismatch`` otherwise."""
    try:
        return engine.conform(clip, what)
    except EngineError as exc:
        raise from_engine(exc) from exc


def _bvh_clip(text: str, engine: Engine, limits: MotionLimits, what: str) -> Clip:
    try:
        doc = BvhDocument.parse(text, source=what)
    except BvhError as exc:  # the reader raises nothing else, whatever the text (fuzzed: tests/model/motion/test_bvh_hostile.py)
        where = what if exc.line is None else f"{what}, line {exc.line}"
        raise ServiceError("bad_motion", f"{where}: {exc.problem}") from exc
    if doc.num_frames == 0:
        raise ServiceError("too_few_frames", f"{what}: the BVH has no frames")
    if doc.num_frames > limits.max_frames:
        raise ServiceError("too_many_frames", f"{what}: {doc.num_frames} frames; at most {limits.max_frames} are accepted")
    offsets = np.abs(np.array([j.offset for j in doc.joints], dtype=np.float64))
    if offsets.size and offsets.max() > limits.max_abs_position:
        raise ServiceError("bad_motion", f"{what}: an OFFSET exceeds {limits.max_abs_position:g} (model units: "
                                         f"{engine.skeleton.units})")
    profile = engine.skeleton.roles.profile
    try:
        # A model trained with its own profile reads files of its rig by the roles its skeleton holds.
        clip = to_clip(doc, profile=profile if profile in BUILTIN_PROFILES else profile_of(engine.skeleton), name=what)
    except SkeletonError as exc:
        raise ServiceError("skeleton_mismatch", f"{what}: {exc}") from exc
    except (ValueError, IndexError) as exc:
        raise ServiceError("bad_motion", f"{what}: {exc}") from exc
    _check_values(clip.rotations.numpy(), clip.root_positions.numpy(), clip.skeleton.names, limits, what, check_norm=False)
    return clip


def _pose_clip(motion: PoseMotion, skeleton: Skeleton, fps: float, limits: MotionLimits, what: str) -> Clip:
    frames = len(motion.rotations)
    if frames > limits.max_frames:
        raise ServiceError("too_many_frames", f"{what}: {frames} frames; at most {limits.max_frames} are accepted")
    if len(motion.root_positions) != frames:
        raise ServiceError("bad_motion", f"{what}: root_positions has {len(motion.root_positions)} frames but rotations "
                                         f"has {frames}; give one root position per frame")
    width = len(motion.rotations[0])
    for t, row in enumerate(motion.rotations):
        if len(row) != width:
            raise ServiceError("bad_motion", f"{what}: rotations[{t}] has {len(row)} joints but rotations[0] has {width}")
    names = motion.joints
    if names is not None and len(names) != width:
        raise ServiceError("bad_motion", f"{what}: joints names {len(names)} joints but each frame has {width} rotations")
    rot = np.asarray(motion.rotations, dtype=np.float64)
    root = np.asarray(motion.root_positions, dtype=np.float64)
    _check_values(rot, root, tuple(names) if names else skeleton.names, limits, what, check_norm=True)
    if names is None:
        if width != skeleton.num_joints:
            raise ServiceError("skeleton_mismatch", f"{what}: {width} rotations per frame but the model's skeleton has "
                                                    f"{skeleton.num_joints} joints (GET /v1/model skeleton.joints); "
                                                    "send them in that order or add `joints` to map them by name")
    else:
        lookup: dict[str, int] = {}
        for i, n in enumerate(_profile_names(tuple(names), skeleton)):  # Mixamo names and the like, read as the model's
            if _plain(n) in lookup:
                raise ServiceError("bad_motion", f"{what}: joint {n!r} is listed twice in `joints`")
            lookup[_plain(n)] = i
        missing = [n for n in skeleton.names if _plain(n) not in lookup]
        if missing:
            raise ServiceError("skeleton_mismatch", f"{what}: `joints` lacks joint(s) of the model's skeleton: "
                                                    f"{', '.join(missing)}")
        rot = rot[:, [lookup[_plain(n)] for n in skeleton.names]]
    rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)
    return Clip(skeleton, torch.from_numpy(rot).float(), torch.from_numpy(root).float(), fps, what)


def _profile_names(names: tuple[str, ...], skeleton: Skeleton) -> tuple[str, ...]:
    """``joints`` under another rig's names (Mixamo, Unreal Mannequin, CMU) as the model's built-in profile reads
    them (its ``aliases``, as for a BVH); as they came when they name the model's joints or fit no alias scheme."""
    have = {_plain(n) for n in names}
    if skeleton.roles.profile not in BUILTIN_PROFILES or all(_plain(n) in have for n in skeleton.names):
        return names
    try:
        return fit_names(names, SkeletonProfile.load(skeleton.roles.profile))[0]
    except SkeletonError:
        return names  # the error that follows names the joints the model lacks


def _check_values(rot: np.ndarray, root: np.ndarray, names: tuple[str, ...], limits: MotionLimits, what: str,
                  check_norm: bool) -> None:
    def joint(j: int) -> str:
        return f"joint {j} ({names[j]!r})" if j < len(names) else f"joint {j}"

    bad = ~np.isfinite(root)
    if bad.any():
        t = int(np.argwhere(bad)[0][0])
        raise ServiceError("bad_motion", f"{what}: root_positions[{t}] is not finite (frame {t})")
    bad = ~np.isfinite(rot)
    if bad.any():
        t, j = (int(v) for v in np.argwhere(bad)[0][:2])
        raise ServiceError("bad_motion", f"{what}: rotation of frame {t}, {joint(j)} is not finite")
    far = np.abs(root) > limits.max_abs_position
    if far.any():
        t = int(np.argwhere(far)[0][0])
        raise ServiceError("bad_motion", f"{what}: root position of frame {t} is beyond {limits.max_abs_position:g} units")
    if check_norm:
        with np.errstate(over="ignore"):  # a component near 1e308 squares to inf: a norm far from 1, refused below
            off = np.abs(1.0 - np.linalg.norm(rot, axis=-1))
        bad = off >= limits.quaternion_tolerance
        if bad.any():
            t, j = (int(v) for v in np.argwhere(bad)[0])
            with np.errstate(over="ignore"):
                norm = float(np.linalg.norm(rot[t, j]))
            raise ServiceError("bad_motion", f"{what}: the quaternion of frame {t}, {joint(j)} has norm {norm:.4g}; "
                                             f"rotations must be unit quaternions (within {limits.quaternion_tolerance:g})")


def _check_resampled_length(clip: Clip, fps: float, limits: MotionLimits, what: str) -> None:
    if not MIN_FPS <= clip.fps <= MAX_FPS:
        raise ServiceError("bad_motion", f"{what}: {clip.fps:g} fps is outside {MIN_FPS:g} to {MAX_FPS:g}")
    frames = int((clip.num_frames - 1) * fps / clip.fps + 1e-9) + 1
    if frames > limits.max_frames:
        raise ServiceError("too_many_frames", f"{what}: {clip.num_frames} frames at {clip.fps:g} fps become {frames} "
                                              f"at the model's {fps:g} fps; at most {limits.max_frames} are accepted")


# ---------------------------------------------------------------------- output
def frames_json(rotations: torch.Tensor, roots: torch.Tensor) -> list[dict[str, np.ndarray]]:
    """Poses ``[{"root_position", "rotations"}]`` as float32 arrays, for ``orjson`` with ``OPT_SERIALIZE_NUMPY``."""
    rot = np.ascontiguousarray(rotations.detach().cpu().numpy(), dtype=np.float32)
    root = np.ascontiguousarray(roots.detach().cpu().numpy(), dtype=np.float32)
    return [{"root_position": root[i], "rotations": rot[i]} for i in range(rot.shape[0])]


def frames_bvh(rotations: torch.Tensor, roots: torch.Tensor, skeleton: Skeleton, fps: float) -> str:
    """BVH text of exactly ``len(rotations)`` frames on ``skeleton``."""
    return dump_clip(Clip(skeleton, rotations.detach().cpu().float(), roots.detach().cpu().float(), fps, "transition"))


def dumps(payload: object) -> bytes:
    """JSON bytes; numpy float32 arrays are written with the shortest text that reads back exactly."""
    return orjson.dumps(payload, option=orjson.OPT_SERIALIZE_NUMPY)

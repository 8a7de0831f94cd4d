"""Registering a style (``POST /v1/styles``) from one clip (``motion``) or from 1 to 5 clips of it (``motions``),
as a blocking function run on a model's work threads; the route files the result on the style store's lane.

Several clips are encoded together into one style (:mod:`model.inference.style_sets`): its id is content-addressed
over every clip, whatever their order. Each clip gets the checks a single clip gets (payload limits, rig mapping,
length), and an error names the clip by its place in ``motions``; the clips of one style must share one rig.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

from model.inference.engine import EncodedStyle
from model.inference.errors import EngineError, TooManyFrames
from model.inference.style_sets import encode_style_set, style_set_context
from model.motion.clip import Clip
from service.errors import ServiceError, from_engine
from service.motion import conform_motion, parse_motion
from service.schemas import BvhMotion, PoseMotion
from service.styles.hints import style_length_hint
from service.styles.host import StyleHost


def registration_clips(model: StyleHost, motions: Sequence[BvhMotion | PoseMotion]) -> list[Clip]:
    """The clips of a ``motions`` registration on the model's rig, each checked; errors say ``motions[i]``."""
    clips: list[Clip] = []
    first: tuple[tuple[str, ...], tuple[int, ...]] | None = None
    for i, motion in enumerate(motions):
        what = f"motions[{i}]"
        raw = parse_motion(motion, model.engine, model.limits, what)
        rig = (tuple(raw.skeleton.names), tuple(raw.skeleton.parents))
        if first is None:
            first = rig
        elif rig != first:
            raise ServiceError("skeleton_mismatch", f"{what} is on another rig than motions[0] (its joints or their "
                                                    "hierarchy differ): the clips of one style are sent on one rig")
        clip = conform_motion(raw, model.engine, what)
        try:
            clips.append(model.engine.style_clip(clip))
        except TooManyFrames as exc:
            hint = style_length_hint(model.engine.config.style_frames_max)
            raise ServiceError("too_many_frames", f"{what}: {exc}{hint}") from exc
        except EngineError as exc:
            raise ServiceError(from_engine(exc).code, f"{what}: {exc}") from exc
    return clips


def encode_clips_registration(model: StyleHost, motions: Sequence[BvhMotion | PoseMotion],
                              name: str) -> tuple[EncodedStyle, list[Clip]]:
    """A ``motions`` registration's encoded style (to file under the caller, with the caller's own name) and its
    clips, as :func:`service.styles.jobs.encode_registration` does for one: the code is computed even when the
    engine has it already, so the time taken never tells that another key registered the same clips."""
    clips = registration_clips(model, motions)
    try:
        style, cached = encode_style_set(model.engine, clips, name)
    except EngineError as exc:
        raise from_engine(exc) from exc
    if cached:
        style_set_context(model.engine, clips)  # the same work, thrown away
    return replace(style, name=name or style.style_id), clips

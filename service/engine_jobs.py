"""The engine work behind each request, as plain blocking functions run on a model's work threads: generate a
transition, prepare a streamed character (the style work they use is :mod:`service.styles`).

Each converts payloads, calls the engine and maps its errors to the contract's codes (:func:`service.errors.from_engine`).
"""

from __future__ import annotations

import secrets
import time
from typing import Any

from model.inference.engine import Character, EncodedStyle
from model.inference.errors import EngineError
from model.motion.clip import Clip
from service.caller import Caller
from service.errors import from_engine
from service.motion import frames_bvh, frames_json, motion_to_clip
from service.registry import LoadedModel
from service.schemas import StartMessage, TransitionRequest
from service.styles import Registered, resolve_style
from service.transition_steps import TransitionSteps
from service.work_queue import Continue


def check_frames(model: LoadedModel, frames: int) -> None:
    """A request's ``frames`` checked by the engine (:meth:`Engine.check_frames`, the one check: 1 to the model's
    longest, ``RSMT_MAX_TRANSITION_FRAMES`` capping it), before any of its motion is read; its error in the
    contract's codes (``too_many_frames`` above the range, ``validation_error`` below it)."""
    try:
        model.engine.check_frames(frames)
    except EngineError as exc:
        raise from_engine(exc) from exc


def new_seed() -> int:
    """A random seed a JavaScript client can hold exactly (at most 2^53 - 1, as a request's seed)."""
    return secrets.randbits(53)


def run_transition(model: LoadedModel, caller: Caller, req: TransitionRequest, queued_at: float,
                   registered: Registered = None) -> dict[str, Any] | Continue[dict[str, Any]]:
    """Generate a whole transition alone (batch of one, so a seed always gives the same frames);
    ``registered``: its ``style_id`` already fetched from the store (:mod:`service.styles.lookups`).

    Returns the response body, after as many slices of stepping as it takes (:class:`Continue`, each on the
    key's next turn of the work queue); ``timing_ms.total`` is left for the caller, which sees the whole request.
    """
    start = time.perf_counter()
    engine = model.engine
    check_frames(model, req.frames)
    context = motion_to_clip(req.context, engine, model.limits, "context")
    target = motion_to_clip(req.target, engine, model.limits, "target")
    style = resolve_style(model, caller, req.style_id, req.style, registered)
    parsed = time.perf_counter()
    seed = req.seed if req.seed is not None else new_seed()
    try:
        ch = engine.prepare(context, target, req.frames, style, seed=seed, deterministic=req.deterministic,
                            exact_arrival=req.exact_arrival, controls=req.controls)
    except EngineError as exc:
        raise from_engine(exc) from exc
    steps = TransitionSteps(engine, ch)
    prepare_s = time.perf_counter() - parsed
    timing = {"queue": round((start - queued_at) * 1e3, 3), "parse": round((parsed - start) * 1e3, 3)}
    return _generate(model, req, ch, style, seed, steps, prepare_s, timing)


def _generate(model: LoadedModel, req: TransitionRequest, ch: Character, style: EncodedStyle, seed: int,
              steps: TransitionSteps, prepare_s: float,
              timing: dict[str, float]) -> dict[str, Any] | Continue[dict[str, Any]]:
    """One slice of a transition's stepping; the response body once it has ended."""
    if not steps.advance():
        return Continue(_generate, (model, req, ch, style, seed, steps, prepare_s, timing))
    engine = model.engine
    rotations, roots = steps.frames()
    body: dict[str, Any] = {"fps": engine.config.fps, "model": model.name, "style_id": style.style_id, "seed": seed,
                            "deterministic": req.deterministic, "reach": reach_body(ch)}
    if req.output == "bvh":
        body["bvh"] = frames_bvh(rotations, roots, engine.skeleton, engine.config.fps)
    else:
        body["frames"] = frames_json(rotations, roots)
    engine_ms = (prepare_s + steps.seconds) * 1e3  # the thread's time, not the turns of other keys between slices
    body["timing_ms"] = {
        "total": 0.0,  # filled by the route, which also sees the wait for this thread
        "engine": round(engine_ms, 3),
        "per_frame": round(engine_ms / req.frames, 4),
        **timing,
    }
    return body


def reach_body(ch: Character) -> dict[str, Any] | None:
    """The ``reach`` field of a response or stream message (docs/api-contract.md): whether the character's
    target can be reached in the frames asked at its style's capture speed; None where the model has no gait
    limits."""
    return None if ch.reach is None else ch.reach.to_dict()


#: A prepared streamed character: the engine's character, its style and its seed.
Prepared = tuple[Character, EncodedStyle, int]


def prepare_character(model: LoadedModel, caller: Caller, msg: StartMessage, character_id: str,
                      registered: Registered = None) -> Prepared | Continue[Prepared]:
    """Build a streamed character's initial state (the scheduler steps it from then on); ``registered``: as
    for :func:`run_transition`. In three slices (:class:`Continue`: the motions read, the style resolved (an
    inline clip read and encoded), the character prepared), so that another key's start waits for one of them
    at most, not for this whole start. The stream session has checked ``frames`` before it reserved the character
    (:func:`check_frames`); the engine's :meth:`Engine.prepare` checks it again last."""
    context = motion_to_clip(msg.context, model.engine, model.limits, "context")
    target = motion_to_clip(msg.target, model.engine, model.limits, "target")
    return Continue(_styled_character, (model, caller, msg, character_id, registered, context, target))


def _styled_character(model: LoadedModel, caller: Caller, msg: StartMessage, character_id: str,
                      registered: Registered, context: Clip,
                      target: Clip) -> Prepared | Continue[Prepared]:
    style = resolve_style(model, caller, msg.style_id, msg.style, registered)
    return Continue(_prepared_character, (model, msg, character_id, context, target, style))


def _prepared_character(model: LoadedModel, msg: StartMessage, character_id: str, context: Clip, target: Clip,
                        style: EncodedStyle) -> Prepared:
    seed = msg.seed if msg.seed is not None else new_seed()
    try:
        ch = model.engine.prepare(context, target, msg.frames, style, seed=seed, deterministic=msg.deterministic,
                                  character_id=character_id, exact_arrival=msg.exact_arrival,
                                  retargeted=msg.retargeted, controls=msg.controls)
    except EngineError as exc:
        raise from_engine(exc) from exc
    return ch, style, seed

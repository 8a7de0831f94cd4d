"""The engine work behind each request, as plain blocking functions run on a model's work threads:
register a style, generate a transition, prepare a streamed character.

Each converts payloads, calls the engine and maps its errors to the contract's codes (:func:`service.errors.from_engine`).
"""

from __future__ import annotations

import secrets
import time
from dataclasses import replace
from typing import Any

import torch

from model.inference.engine import Character, EncodedStyle
from model.inference.errors import EngineError, TooManyFrames
from model.motion.clip import Clip
from service.builtin_styles import builtin_style, is_builtin
from service.errors import ServiceError, from_engine
from service.motion import frames_bvh, frames_json, motion_to_clip
from service.registry import LoadedModel
from service.schemas import BvhMotion, PoseMotion, StartMessage, TransitionRequest
from service.style_book import Caller
from service.style_hints import builtin_suggestion, style_length_hint
from service.style_store import StyleEntry
from service.transition_steps import TransitionSteps
from service.work_queue import Continue


def lookup_style(model: LoadedModel, caller: Caller, style_id: str) -> EncodedStyle:
    """One of the caller's registered styles (an admin's: anyone's); ``unknown_style`` otherwise, also when
    another key registered it. A ``builtin:NAME`` id is one of the bundle's built-in styles, for every key."""
    if is_builtin(style_id):
        return builtin_style(model.engine, model.name, style_id)
    style = model.book.get(caller, style_id)
    if style is None:
        raise ServiceError("unknown_style", f"no style {style_id!r} for model {model.name!r} under this API key: "
                                            "register the clip with POST /v1/styles (ids are content hashes, so "
                                            "re-registering gives the same id; styles live in memory only, per key, "
                                            "and are evicted and lost on restart)."
                                            + builtin_suggestion(style_id, model.engine.bundle.styles))
    return style


def encode_style(model: LoadedModel, motion: BvhMotion | PoseMotion, name: str) -> tuple[EncodedStyle, bool]:
    return encode_clip(model, motion_to_clip(motion, model.engine, model.limits, "style"), name)


def encode_clip(model: LoadedModel, clip: Clip, name: str) -> tuple[EncodedStyle, bool]:
    try:
        return model.engine.encode_style(clip, name)
    except TooManyFrames as exc:  # a whole take, say: say how to cut it
        raise ServiceError("too_many_frames", str(exc) + style_length_hint(model.engine.config.style_frames_max)) from exc
    except EngineError as exc:
        raise from_engine(exc) from exc


#: A ``style_id`` already looked up on the style store's lane (:mod:`service.style_lookups`): the style, the
#: ``unknown_style`` error to raise once the request's motion has been checked (the order errors come in), or
#: None (no id, or a built-in one).
Registered = EncodedStyle | ServiceError | None


def resolve_style(model: LoadedModel, caller: Caller, style_id: str | None,
                  motion: BvhMotion | PoseMotion | None, registered: Registered = None) -> EncodedStyle:
    if isinstance(registered, ServiceError):
        raise registered
    if registered is not None:
        return registered
    if style_id is not None:
        return lookup_style(model, caller, style_id)
    assert motion is not None
    # An inline clip costs the same work whether or not the engine's shared memo already has its code: a clip
    # another key registered or sent would otherwise make this request faster, a timing tell across keys.
    clip = motion_to_clip(motion, model.engine, model.limits, "style")
    style, cached = encode_clip(model, clip, "inline")
    if cached:
        spend_encoding(model, clip)
    return style


def style_info(model: LoadedModel, style: StyleEntry, cached: bool) -> dict[str, Any]:
    return {"style_id": style.style_id, "name": style.name, "frames": style.frames, "clips": style.clips,
            "cached": cached, "model": model.name}


def encode_registration(model: LoadedModel, motion: BvhMotion | PoseMotion, name: str) -> tuple[EncodedStyle, Clip]:
    """A registration's encoded style (to file under the caller, with the caller's own name) and its clip;
    the route files it on the style store's lane (:mod:`service.style_lookups`).

    Content is deduplicated below the keys (one code, one stored clip), names above them: the entry filed
    is the shared code under this caller's name, so no key ever sees the name another key chose. And the
    code is computed even when the engine already has it, so that registering a clip another key has takes
    as long as registering a new one (the time would otherwise tell that someone registered it).
    """
    clip = motion_to_clip(motion, model.engine, model.limits, "style")
    style, cached = encode_clip(model, clip, name)  # the store keeps the clip (RSMT_STYLE_STORE=redis: for other replicas)
    if cached:
        spend_encoding(model, clip)
    return replace(style, name=name or style.style_id), clip


def spend_encoding(model: LoadedModel, clip: Clip) -> None:
    """The work :meth:`Engine.encode_style` does for a clip it has not seen (its code and style context),
    done and thrown away."""
    engine = model.engine
    conformed = engine.conform(clip, "style clip")
    with torch.inference_mode():
        engine.weights("").net.style_context(engine.style_code(conformed))


def new_seed() -> int:
    """A random seed a JavaScript client can hold exactly (at most 2^53 - 1, as a request's seed)."""
    return secrets.randbits(53)


def run_transition(model: LoadedModel, caller: Caller, req: TransitionRequest, queued_at: float,
                   registered: Registered = None) -> dict[str, Any] | Continue[dict[str, Any]]:
    """Generate a whole transition alone (batch of one, so a seed always gives the same frames);
    ``registered``: its ``style_id`` already fetched from the store (:mod:`service.style_lookups`).

    Returns the response body, after as many slices of stepping as it takes (:class:`Continue`, each on the
    key's next turn of the work queue); ``timing_ms.total`` is left for the caller, which sees the whole request.
    """
    start = time.perf_counter()
    engine = model.engine
    model.check_frames(req.frames)
    context = motion_to_clip(req.context, engine, model.limits, "context")
    target = motion_to_clip(req.target, engine, model.limits, "target")
    style = resolve_style(model, caller, req.style_id, req.style, registered)
    parsed = time.perf_counter()
    seed = req.seed if req.seed is not None else new_seed()
    try:
        ch = engine.prepare(context, target, req.frames, style, seed=seed, deterministic=req.deterministic,
                            exact_arrival=req.exact_arrival, style_strength=req.style_strength)
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
    at most, not for this whole start."""
    model.check_frames(msg.frames)
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
                                  retargeted=msg.retargeted, style_strength=msg.style_strength)
    except EngineError as exc:
        raise from_engine(exc) from exc
    return ch, style, seed

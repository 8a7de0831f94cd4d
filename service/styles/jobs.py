"""The style work behind requests, as plain blocking functions run on a model's work threads (or on the style
store's lane for a lookup): find a caller's registered or built-in style, encode a clip (inline, or to register),
resolve a request's style, describe a registered one.

Each takes the served model as a :class:`~service.styles.host.StyleHost` (its name, engine, limits and style
store) and maps the engine's errors to the contract's codes (:func:`service.errors.from_engine`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import torch

from model.inference.engine import EncodedStyle
from model.inference.errors import EngineError, TooManyFrames
from model.motion.clip import Clip
from service.caller import Caller
from service.errors import ServiceError, from_engine
from service.motion import motion_to_clip
from service.schemas import BvhMotion, PoseMotion
from service.styles.builtin import builtin_style, is_builtin
from service.styles.hints import builtin_suggestion, style_length_hint
from service.styles.host import StyleHost
from service.styles.store import StyleEntry


def lookup_style(model: StyleHost, caller: Caller, style_id: str) -> EncodedStyle:
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


def encode_clip(model: StyleHost, clip: Clip, name: str) -> tuple[EncodedStyle, bool]:
    try:
        return model.engine.encode_style(clip, name)
    except TooManyFrames as exc:  # a whole take, say: say how to cut it
        raise ServiceError("too_many_frames", str(exc) + style_length_hint(model.engine.config.style_frames_max)) from exc
    except EngineError as exc:
        raise from_engine(exc) from exc


#: A ``style_id`` already looked up on the style store's lane (:mod:`service.styles.lookups`): the style, the
#: ``unknown_style`` error to raise once the request's motion has been checked (the order errors come in), or
#: None (no id, or a built-in one).
Registered = EncodedStyle | ServiceError | None


def resolve_style(model: StyleHost, caller: Caller, style_id: str | None,
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


def style_info(model: StyleHost, style: StyleEntry, cached: bool) -> dict[str, Any]:
    return {"style_id": style.style_id, "name": style.name, "frames": style.frames, "clips": style.clips,
            "cached": cached, "model": model.name}


def encode_registration(model: StyleHost, motion: BvhMotion | PoseMotion, name: str) -> tuple[EncodedStyle, Clip]:
    """A registration's encoded style (to file under the caller, with the caller's own name) and its clip;
    the route files it on the style store's lane (:mod:`service.styles.lookups`).

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


def spend_encoding(model: StyleHost, clip: Clip) -> None:
    """The work :meth:`Engine.encode_style` does for a clip it has not seen (its code and style context),
    done and thrown away."""
    engine = model.engine
    conformed = engine.conform(clip, "style clip")
    with torch.inference_mode():
        engine.weights("").net.style_context(engine.style_code(conformed))



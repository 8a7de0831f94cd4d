"""A style from several clips: each clip encoded on its own, the codes joined along the time axis.

The sampler reads a style code ``[T', C]`` in two ways (:mod:`model.nets.sampler`): FiLM takes its time mean,
attention attends over its time steps. Joining the clips' codes along time gives both what a style of
several clips should: FiLM reads the mean over every clip's steps (each clip weighted by its length), and
every frame attends over all clips' steps at once, so it can draw on whichever clip fits the moment. Each
clip goes through the encoder alone, so its convolutions never read across the seam between two clips.

Clip order does not matter: the codes are joined in the order of the clips' own content hashes, and the
set's id is a hash of those hashes, sorted; the same clips in any order give the same id and the same
context, bit for bit. A set of one clip is that clip's style exactly (same id, same code) as
:meth:`Engine.encode_style` gives it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

import torch

from model.inference.character import EncodedStyle
from model.inference.engine import Engine
from model.inference.errors import EngineError
from model.inference.style_codes import clip_content_hash
from model.motion.clip import Clip

MAX_STYLE_CLIPS = 5


class StyleClipCount(EngineError):
    """A style set of no clips, or of more than :data:`MAX_STYLE_CLIPS`."""


def style_set_id(clip_ids: Sequence[str], version: str) -> str:
    """The id of a style encoded from clips with these ids (each a :func:`clip_content_hash`, which already
    covers the rig, the rate and the model version): one clip's id for one clip, else a hash of the sorted ids."""
    if len(clip_ids) == 1:
        return clip_ids[0]
    digest = hashlib.sha256(b"rsmt-style-set\0")
    digest.update(version.encode() + b"\0")
    for sid in sorted(clip_ids):
        digest.update(sid.encode() + b"\0")
    return "sty_" + digest.hexdigest()[:24]


def style_set_clips(engine: Engine, clips: Sequence[Clip]) -> list[Clip]:
    """Each clip on the model's rig with its length checked (:meth:`Engine.style_clip`); an error names the
    clip by its place in ``clips`` (from 0)."""
    if not 1 <= len(clips) <= MAX_STYLE_CLIPS:
        raise StyleClipCount(f"a style is encoded from 1 to {MAX_STYLE_CLIPS} clips; got {len(clips)}")
    out = []
    for i, clip in enumerate(clips):
        try:
            out.append(engine.style_clip(clip))
        except EngineError as exc:
            raise type(exc)(f"style clip {i}: {exc}" if len(clips) > 1 else str(exc)) from exc
    return out


def style_set_context(engine: Engine, clips: Sequence[Clip], weights: str = "") -> tuple[str, Any]:
    """The id and style context of clips already checked by :func:`style_set_clips`, by the weight set
    ``weights``: each clip's code, the codes joined along time in the order of the clips' ids."""
    ws = engine.weights(weights)
    ids = [clip_content_hash(c, ws.version) for c in clips]
    order = sorted(range(len(clips)), key=lambda i: ids[i])
    codes = [engine.style_code(clips[i], weights) for i in order]
    with torch.inference_mode():
        ctx = ws.net.style_context(codes[0] if len(codes) == 1 else torch.cat(codes, dim=1))
    return style_set_id(ids, ws.version), ctx


def encode_style_set(engine: Engine, clips: Sequence[Clip], name: str = "",
                     weights: str = "") -> tuple[EncodedStyle, bool]:
    """One style from 1 to :data:`MAX_STYLE_CLIPS` clips of it, or its cached encoding (the bool says which),
    kept in the engine's style cache by its real size (its context grows with every clip's steps)."""
    checked = style_set_clips(engine, clips)
    if len(checked) == 1:
        return engine.encode_style(checked[0], name, weights)
    ws = engine.weights(weights)
    sid = style_set_id([clip_content_hash(c, ws.version) for c in checked], ws.version)
    cached = engine.styles.get(sid)
    if cached is not None:
        return cached, True
    sid, ctx = style_set_context(engine, checked, weights)
    style = EncodedStyle(sid, name or sid, sum(c.num_frames for c in checked), ctx, ctx.nbytes, weights,
                         clips=len(checked))
    engine.styles.put(sid, style)
    return style, False

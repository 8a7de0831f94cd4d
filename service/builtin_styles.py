"""Built-in styles: the style clips a bundle ships (``BUNDLE/styles/``), served to every API key as
``builtin:NAME`` wherever a ``style_id`` is accepted, and listed in the model's description.

They are encoded on first use (once per model, under a lock; a few milliseconds each) and kept
for the life of the process: no key owns them, nothing evicts them and ``DELETE /v1/styles`` does
not see them. The id a response reports is the built-in id, not a content hash.
"""

from __future__ import annotations

import dataclasses
import threading
import weakref
from typing import TYPE_CHECKING, Any

from model.inference.errors import EngineError
from service.errors import ServiceError, from_engine

if TYPE_CHECKING:
    from model.inference.engine import EncodedStyle, Engine

PREFIX = "builtin:"

_encoded: weakref.WeakKeyDictionary[Engine, dict[str, EncodedStyle]] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def is_builtin(style_id: str) -> bool:
    return style_id.startswith(PREFIX)


def builtin_list(engine: Engine) -> list[dict[str, Any]]:
    """``[{"style_id", "name", "frames"}]`` of the model's built-in styles, by name."""
    styles = engine.bundle.styles
    return [{"style_id": PREFIX + name, "name": name, "frames": styles[name].frames} for name in sorted(styles)]


def builtin_style(engine: Engine, model_name: str, style_id: str) -> EncodedStyle:
    """The encoded built-in style ``builtin:NAME``; ``unknown_style`` naming the ones there are otherwise."""
    name = style_id[len(PREFIX):]
    style = engine.bundle.styles.get(name)
    if style is None:
        known = ", ".join(PREFIX + n for n in sorted(engine.bundle.styles)) or "none"
        raise ServiceError("unknown_style", f"model {model_name!r} has no built-in style {style_id!r}; its built-in "
                                            f"styles: {known} (GET /v1/model builtin_styles)")
    with _lock:
        done = _encoded.setdefault(engine, {})
        encoded = done.get(name)
        if encoded is None:
            try:
                raw, _ = engine.encode_style(style.clip, name)
            except EngineError as exc:
                raise from_engine(exc) from exc
            # A copy under the built-in id: the engine's own cache keeps its content-hash entry.
            encoded = done[name] = dataclasses.replace(raw, style_id=PREFIX + name, name=name)
    return encoded

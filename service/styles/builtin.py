"""Built-in styles: the style codes a bundle ships (``BUNDLE/styles/``, encoded when it was packaged), served
to every API key as ``builtin:NAME`` wherever a ``style_id`` is accepted, listed in the model's description
and in ``GET /v1/styles`` (``builtin: true``).

Nothing is encoded at serve time: the stored code is the style. A style with an adapter (a style fine-tuned
into the bundle, :mod:`model.inference.bundle_adapters`) runs on the adapter's weights, every other on the
bundle's own. No key owns a built-in style, none counts
against a key's styles, nothing evicts them, and ``DELETE /v1/styles`` refuses them. The id a response
reports is the built-in id, not a content hash.
"""

from __future__ import annotations

import threading
import weakref
from typing import TYPE_CHECKING, Any

from model.inference.engine import EncodedStyle
from service.errors import ServiceError
from service.schemas import BUILTIN_PREFIX as PREFIX

if TYPE_CHECKING:
    from model.inference.engine import Engine


_served: weakref.WeakKeyDictionary[Engine, dict[str, EncodedStyle]] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def is_builtin(style_id: str) -> bool:
    return style_id.startswith(PREFIX)


def builtin_list(engine: Engine) -> list[dict[str, Any]]:
    """``[{"style_id", "name", "frames"}]`` of the model's built-in styles, by name."""
    styles = engine.bundle.styles
    return [{"style_id": PREFIX + name, "name": name, "frames": styles[name].frames} for name in sorted(styles)]


def builtin_style(engine: Engine, model_name: str, style_id: str) -> EncodedStyle:
    """The built-in style ``builtin:NAME`` (its stored code); ``unknown_style`` naming the ones there are otherwise."""
    name = style_id[len(PREFIX):]
    style = engine.bundle.styles.get(name)
    if style is None:
        known = ", ".join(PREFIX + n for n in sorted(engine.bundle.styles)) or "none"
        raise ServiceError("unknown_style", f"model {model_name!r} has no built-in style {style_id!r}; its built-in "
                                            f"styles: {known} (GET /v1/styles, GET /v1/model builtin_styles)")
    with _lock:  # one EncodedStyle per style and engine, so every request shares the same object
        served = _served.setdefault(engine, {})
        encoded = served.get(name)
        if encoded is None:
            encoded = served[name] = EncodedStyle(PREFIX + name, name, style.frames, style.context, style.nbytes,
                                                     style.weights, gait=name)
    return encoded

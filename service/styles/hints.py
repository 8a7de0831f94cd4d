"""What the style errors tell a caller to do: the built-in id a bare style name meant, and how to cut a clip
that is longer than the model reads."""

from __future__ import annotations

from collections.abc import Iterable

from service.schemas import BUILTIN_PREFIX as PREFIX


def builtin_suggestion(style_id: str, builtin_names: Iterable[str]) -> str:
    """`` Did you mean builtin:NAME?`` when ``style_id`` is a built-in style's bare name (any case), else ``""``."""
    wanted = style_id.strip().lower()
    for name in builtin_names:
        if name.lower() == wanted:
            return f" Did you mean {PREFIX}{name}? (the model's built-in style, usable by every key as style_id)"
    return ""


def style_length_hint(max_frames: int) -> str:
    """How to send a style clip within ``max_frames`` frames, with the client options that cut one."""
    return (f"; cut it to at most {max_frames} frames: `rsmt client styles add CLIP --start S --frames {max_frames}` "
            "sends a part of your choice, and the Python, Unity and Unreal clients send the middle of a longer clip "
            "by themselves")

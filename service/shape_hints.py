"""What a request of a common wrong shape should have sent instead: a Motion field given a string (a style's
name in ``style``, BVH text without its ``{"bvh": ...}`` object), and a BVH file sent as the whole body.

:func:`motion_errors` turns pydantic's errors on a Motion (one per branch of ``BvhMotion | PoseMotion``, named
after the classes) into one line that names the fix; the error handlers use it for HTTP and the WebSocket.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from service.schemas import BUILTIN_PREFIX as PREFIX

# pydantic names each branch of the Motion union after its class in an error's location.
MOTION_BRANCHES = {"BvhMotion": "bvh", "PoseMotion": "root_positions"}
BVH_OBJECT = '{"bvh": "<the BVH file\'s text>"}'
POSES_OBJECT = '{"root_positions": [[x, y, z], ...], "rotations": [[[x, y, z, w], ...], ...]}'
# How to wrap a file with jq, for the messages: its text as one JSON string, inside the object.
JQ_WRAP = "jq -Rs '{bvh: .}' walk.bvh"


def looks_like_bvh(text: str) -> bool:
    """Whether ``text`` starts as a BVH file does (``HIERARCHY``, after blanks or a byte-order mark)."""
    return text.lstrip("\ufeff \t\r\n")[:9].upper() == "HIERARCHY"


def raw_bvh_body_hint(body_start: bytes) -> str:
    """A sentence for a 415 whose body is a BVH file sent as it is (``""`` for any other body)."""
    if not looks_like_bvh(body_start[:64].decode("utf-8", "replace")):
        return ""
    return (f" This body is a BVH file: send it inside JSON, as the text of a Motion, {BVH_OBJECT}, in the field that "
            f"takes it (\"context\", \"target\", \"style\", or \"motion\" of POST /v1/styles); `{JQ_WRAP}` makes "
            "that object from a file")


def motion_errors(errors: Sequence[Mapping[str, Any]],
                  builtin_names: Iterable[str] = ()) -> tuple[list[str], list[Mapping[str, Any]]]:
    """The messages for errors on Motion fields, and the other errors left as they were.

    A Motion given something other than an object gets one message naming what to send (for ``style``, the
    ``style_id`` to use instead); a Motion object of the wrong shape keeps only the errors of the branch it
    meant (``bvh`` given: BVH text; else JSON poses), located without the class names.
    """
    names = list(builtin_names)
    by_field: dict[tuple[Any, ...], list[Mapping[str, Any]]] = {}
    others: list[Mapping[str, Any]] = []
    for err in errors:
        loc = _located(err)
        at = next((i for i, p in enumerate(loc) if p in MOTION_BRANCHES), None)
        if at is None:
            others.append(err)
        else:
            by_field.setdefault(loc[:at], []).append(err)
    messages = []
    for field, errs in by_field.items():
        where = ".".join(str(p) for p in field) or "body"
        whole = [e for e in errs if len(_located(e)) == len(field) + 1]  # a branch refused the value itself
        if whole and len(whole) == len(errs):
            messages.append(f"{where}: {_not_an_object(field, whole[0].get('input'), names)}")
            continue
        # An object: it meant BVH text unless it has no "bvh" (then JSON poses).
        no_bvh = any(_located(e) == (*field, "BvhMotion", "bvh") and e.get("type") == "missing" for e in errs)
        meant = "PoseMotion" if no_bvh else "BvhMotion"
        for err in errs:
            loc = _located(err)
            if meant in loc:
                rest = loc[loc.index(meant) + 1:]
                messages.append(f"{'.'.join(str(p) for p in (*field, *rest))}: {err.get('msg', 'invalid')}")
    return messages, others


def _located(err: Mapping[str, Any]) -> tuple[Any, ...]:
    """An error's place in the request body."""
    return tuple(p for p in err.get("loc", ()) if p != "body")


def _not_an_object(field: tuple[Any, ...], value: Any, builtin_names: list[str]) -> str:
    got = "a string" if isinstance(value, str) else "an array" if isinstance(value, list) else \
        "null" if value is None else "true or false" if isinstance(value, bool) else "a number"
    motion = f"a Motion, an object: BVH text as {BVH_OBJECT}, or JSON poses {POSES_OBJECT}"
    if isinstance(value, str) and field[-1:] == ("style",):
        fix = _style_id_fix(value, builtin_names)
        return f"takes a style clip ({motion}), not {got}; a style by its id goes in style_id: {fix}"
    if isinstance(value, str) and looks_like_bvh(value):
        return f"BVH text goes inside an object, {BVH_OBJECT}, not as a bare string (`{JQ_WRAP}` makes it from a file)"
    return f"expects {motion}; got {got}"


def _style_id_fix(value: str, builtin_names: list[str]) -> str:
    """What to send in ``style_id`` for a string sent as ``style``."""
    wanted = value.strip()
    match = next((n for n in builtin_names if n.lower() == wanted.lower()), None)
    if match is not None:
        return f'send "style_id": "{PREFIX}{match}" instead of "style" (the model\'s built-in style {match!r})'
    if wanted.startswith(("sty_", PREFIX)):
        return f'send "style_id": "{wanted[:80]}" instead of "style"'
    known = ", ".join(f"{PREFIX}{n}" for n in builtin_names[:8])
    return ('send "style_id": "<id>" instead of "style": an id from POST /v1/styles or builtin:NAME '
            f"({'the models have ' + known + '; ' if known else ''}GET /v1/styles lists them)")

"""Registered styles fetched on the style store's lane (:mod:`service.styles.store.lane`), before the engine work
that uses them is queued: a request naming a ``style_id`` waits for the store on the lane (503 after its
timeout), never on a model's work or stream-setup threads, so requests without one are not held up by it."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from service.errors import ServiceError
from service.styles.builtin import is_builtin
from service.styles.jobs import Registered, lookup_style

if TYPE_CHECKING:
    from collections.abc import Sequence

    from model.inference.engine import EncodedStyle
    from model.motion.clip import Clip
    from service.caller import Caller
    from service.styles.host import StyleHost
    from service.styles.store.lane import StoreLane


async def registered_style(lane: StoreLane, model: StyleHost, caller: Caller, style_id: str | None) -> Registered:
    """The caller's registered style ``style_id`` from the store, or its ``unknown_style`` error (raised by the
    job once the request's motion is checked, as before); None for no id or a built-in one (the engine's own,
    resolved with the rest of the job). A store that does not answer raises ``style_store_unavailable``."""
    if style_id is None or is_builtin(style_id):
        return None
    try:
        return await lane.call(lookup_style, model, caller, style_id)
    except ServiceError as exc:
        if exc.code == "unknown_style":
            return exc
        raise


async def file_style(lane: StoreLane, model: StyleHost, owner: str, style: EncodedStyle,
                     clips: Sequence[Clip]) -> bool:
    """File an encoded registration (of one clip or several) under ``owner``; True when the owner had it already."""
    return await lane.call(model.book.add, owner, style, clips)


async def on_lane(lane: StoreLane, fn: Any, *args: Any) -> Any:
    """Any other store call (listing, fetching, deleting) on the lane."""
    return await lane.call(fn, *args)

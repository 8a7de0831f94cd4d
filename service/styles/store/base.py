"""What every style store answers (:class:`StyleStore`) and what a listing shows (:class:`StyleEntry`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from service.caller import Caller

if TYPE_CHECKING:
    from model.inference.engine import EncodedStyle
    from model.motion.clip import Clip


class StyleEntry(Protocol):
    """What listing a style shows: an :class:`EncodedStyle` or a stored style's :class:`StyleMeta`."""

    @property
    def style_id(self) -> str: ...

    @property
    def name(self) -> str: ...

    @property
    def frames(self) -> int: ...

    @property
    def clips(self) -> int: ...


@dataclass(frozen=True)
class StyleMeta:
    """A stored style without its code: id, name, length (of all its clips) and how many clips."""

    style_id: str
    name: str
    frames: int
    clips: int = 1


class StyleStore(Protocol):
    """One model's registered styles, by owner. Calls may block (Redis): run them off the event loop.

    A store that cannot be reached raises :class:`service.errors.ServiceError` ``style_store_unavailable``.
    """

    def add(self, owner: str, style: EncodedStyle, clips: Sequence[Clip]) -> bool:
        """File ``style`` (encoded from ``clips``, on the model's rig) under ``owner``; True when the owner already
        had it. A style of n clips counts as n of the owner's styles against the per-key cap."""
        ...

    def get(self, caller: Caller, style_id: str) -> EncodedStyle | None:
        """The caller's style, encoded (on a replica that has not encoded it yet: now), marked as used."""
        ...

    def peek(self, caller: Caller, style_id: str) -> StyleEntry | None:
        """The caller's style without encoding it or touching its recency."""
        ...

    def styles_of(self, caller: Caller) -> Sequence[StyleEntry]:
        """The caller's styles, least recently used first (an admin's: everyone's, one entry per id)."""
        ...

    def delete(self, caller: Caller, style_id: str) -> bool:
        """Forget the caller's entry (an admin's: every owner's); True when there was one."""
        ...

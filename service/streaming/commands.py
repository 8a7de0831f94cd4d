"""What the event loop asks of a scheduler's step thread, one dataclass per kind of command.

Connections queue commands on the loop; the step thread applies them at the start of its next tick,
before the step. Membership commands (:class:`Add`, :class:`Remove`, :class:`Park`, :class:`Unpark`)
are fire-and-forget; a :class:`Request` (:class:`Retarget`, :class:`SetStyle`) is awaited, and its
``reply`` gets the ``seq`` of the first frame it affects, or the error that refused it.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import ClassVar

from model.inference.engine import EncodedStyle
from model.motion.clip import Clip
from service.streaming.stream import Stream


@dataclass(frozen=True, eq=False, kw_only=True)
class Command:
    stream: Stream
    kind: ClassVar[str]  # named in logs and error messages


@dataclass(frozen=True, eq=False, kw_only=True)
class Add(Command):
    """Start stepping a prepared character."""

    kind = "add"


@dataclass(frozen=True, eq=False, kw_only=True)
class Remove(Command):
    """Stop a character (cancelled or its connection gone)."""

    kind = "remove"


@dataclass(frozen=True, eq=False, kw_only=True)
class Park(Command):
    """Take a character out of its batch, state kept: its connection's send queue is full."""

    kind = "park"


@dataclass(frozen=True, eq=False, kw_only=True)
class Unpark(Command):
    """Put a parked character back into its batch."""

    kind = "unpark"


@dataclass(frozen=True, eq=False, kw_only=True)
class Request(Command):
    """A change to a live character that its sender awaits."""

    reply: asyncio.Future[int]


@dataclass(frozen=True, eq=False, kw_only=True)
class Retarget(Request):
    """A new target and/or number of remaining frames, from the next frame on."""

    kind = "retarget"
    target: Clip | None
    frames: int | None


@dataclass(frozen=True, eq=False, kw_only=True)
class SetStyle(Request):
    """Another style, from the next frame on."""

    kind = "style"
    style: EncodedStyle


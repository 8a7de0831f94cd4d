"""One streamed character (:class:`Stream`) and the two sides it is handed between: its connection's
:class:`Outbox`, which sends its frames, and its model's :class:`Stepper`, which generates them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from model.inference.engine import Character, EncodedStyle
from model.motion.clip import Clip

PACES = ("realtime", "asap")


class Outbox(Protocol):
    """What a connection offers the scheduler (implemented by :class:`service.streaming.connection.Connection`)."""

    encoding: str

    def deliver_frame(self, stream: Stream, seq: int, payload: str | bytes, now: float) -> None: ...

    def deliver_end(self, stream: Stream, reason: str) -> None: ...

    def deliver_failure(self, stream: Stream, message: str) -> None: ...


class Stepper(Protocol):
    """What a character's scheduler offers its connection and the message protocol
    (implemented by :class:`service.streaming.scheduler.Scheduler`)."""

    def drop(self, stream: Stream) -> None: ...

    def park(self, stream: Stream, now: float) -> None: ...

    def unpark(self, stream: Stream) -> None: ...

    async def retarget(self, stream: Stream, target: Clip | None, frames: int | None) -> int: ...

    async def set_style(self, stream: Stream, style: EncodedStyle) -> int: ...


@dataclass(eq=False)
class Stream:
    """One streamed character: the engine's :class:`Character` plus its connection, slot and pacing.

    Fields below ``pace`` belong to the event loop; the step thread reads only the first ones.
    """

    character: Character
    outbox: Outbox
    slot: int
    pace: str
    fps: float
    encoding: str
    queued: int = 0  # frames generated and not yet sent
    sent: int = 0
    parked_at: float | None = None  # loop time it was parked for a full queue
    start_time: float | None = None  # loop time frame 0 was due
    ended: bool = False  # no more frames are taken (arrived, cancelled or dropped)
    cancelled: bool = False
    scheduler: Stepper | None = None  # set by Scheduler.add
    model: str = ""
    owner: str = ""  # the API key's owner digest: whose share of the step budget it steps on
    last_due: float = 0.0

    @property
    def id(self) -> str:
        return self.character.id

    @property
    def parked(self) -> bool:
        return self.parked_at is not None

    def due(self, seq: int, now: float) -> float:
        """Loop time at which frame ``seq`` should leave: now for asap; on the fps clock for realtime.

        A realtime frame generated more than one frame period late moves the clock instead of
        bursting: the client gets it at once and the following ones one period apart.
        """
        if self.pace == "asap":
            return now
        period = 1.0 / self.fps
        if self.start_time is None:
            self.start_time = now - seq * period
        due = self.start_time + seq * period
        late = now - due
        if late > period:
            self.start_time += late - period
            due = now - period
        return due

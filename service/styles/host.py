"""What the style functions need of a served model, and nothing more: its name (for messages), its engine (to
encode and run styles), its payload limits (to read a clip) and its style store (to file and find registered
styles). A loaded model (:class:`service.registry.LoadedModel`) is one, by its shape; the styles package never
imports the registry."""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from model.inference.engine import Engine
    from service.motion import MotionLimits
    from service.styles.store import StyleStore


class StyleHost(Protocol):
    """A served model as the style functions see it."""

    @property
    def name(self) -> str: ...

    @property
    def engine(self) -> Engine: ...

    @property
    def limits(self) -> MotionLimits: ...

    @property
    def book(self) -> StyleStore: ...

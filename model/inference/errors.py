"""What the engine refuses, as exception types named for the problem (a caller such as the service maps
them to its own codes): motion on another skeleton, too few or too many frames, a length out of range."""

from __future__ import annotations


class EngineError(ValueError):
    """A request the engine cannot serve; the message says what is wrong and what is accepted."""


class SkeletonMismatch(EngineError):
    """The motion lacks joints of the model's skeleton (the message names them)."""


class TooFewFrames(EngineError):
    """A clip is shorter than the model needs (a style clip, or the context of a transition)."""


class TooManyFrames(EngineError):
    """A clip or a transition is longer than the model accepts."""


class NoNeutralStyle(EngineError):
    """A style strength other than 1 asked where there is no neutral style: a model without built-in styles, or an
    engine running a source other than the network."""


class FramesOutOfRange(EngineError):
    """A transition length outside 1 to the model's longest, where neither of the above applies."""

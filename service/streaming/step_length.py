"""How long a batch's step takes, as the scheduler's decisions read it: a running length that follows the
last few steps (the asap gate's estimate, each lane's, each key's asap step)."""

from __future__ import annotations

SMOOTHING = 0.3  # weight of the newest step in a running step length


def smoothed(old: float | None, seconds: float) -> float:
    """The running step length after a step of ``seconds``: that step when none was seen (``old`` None), else
    ``SMOOTHING`` of it and the rest of ``old``."""
    return seconds if old is None else (1 - SMOOTHING) * old + SMOOTHING * seconds

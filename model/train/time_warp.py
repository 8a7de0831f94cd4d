"""Time-warped training windows: ground truth for transitions asked to go faster or slower.

A game asks for transitions the capture never shows: twice the distance in the same time, or half
the time for the same distance. The changed-control windows of the sampler stage put such requests
in training, but without ground truth their losses (target, feet, critics) cannot say how the legs
should move, and the sampler learned to arrive by sliding (docs/experiments/2026-11-25-steering.md).

A warped window gives such a request a ground truth taken from real motion. Its context is the
capture as it was; from the last context frame on, the capture is replayed at a speed that ramps
from 1 to a constant ``v`` over ``ramp`` frames, so the transition of ``L`` frames covers ``k L``
frames of the capture (``k``: the window's factor) and ends on a real pose ``k L`` frames on. The
path, the foot contacts and the poses are the capture's (feet planted stay planted); only the
cadence changes, smoothly, from the context's. With ``k = 2`` a walk arrives where it would have
been after 80 frames in 40; with ``k = 0.5`` it covers half its usual ground.

Source times of the transition's frames ``t = 1..L`` after the last context frame:
``tau(t) = t + (v - 1) t^2 / (2 R)`` for ``t <= R`` and ``t + (v - 1) (t - R / 2)`` after, with
``R = min(ramp, L / 2)`` and ``v`` chosen so that ``tau(L) = k L``; the speed ``tau'`` is continuous,
1 at the context's end. Poses between captured frames are interpolated (positions linearly,
rotations by normalised linear interpolation of neighbouring frames, whose signs agree).
"""

from __future__ import annotations

import math

import torch

Tensor = torch.Tensor

MAX_FACTOR = 4.0  # with the ramp at most half the transition, 1/4 is the slowest factor that never stops the replay


def warp_speed(length: int, factor: Tensor, ramp: int) -> Tensor:
    """The constant speed ``v [B]`` after the ramp that makes ``length`` frames cover ``factor * length``."""
    if length < 1 or ramp < 0:
        raise ValueError(f"a warp needs a length of at least 1 and a ramp of 0 or more, got {length} and {ramp}")
    r = _ramp(length, ramp)
    return 1.0 + (factor.to(torch.float64) - 1.0) * length / (length - r / 2.0)


def _ramp(length: int, ramp: int) -> float:
    """The ramp's length in frames: at most half the transition, so factors down to 1/4 never replay backwards."""
    return min(float(ramp), length / 2.0)


def warp_times(length: int, factor: Tensor, ramp: int) -> tuple[Tensor, Tensor]:
    """Source times ``tau [B, length]`` of the transition's frames 1..length (counted from the last
    context frame) and the replay speed ``tau' [B, length]`` there, for factors ``[B]``."""
    if bool((factor <= 0).any()):
        raise ValueError("warp factors must be positive")
    r = _ramp(length, ramp)
    v = warp_speed(length, factor, ramp).unsqueeze(1)
    t = torch.arange(1, length + 1, dtype=torch.float64).unsqueeze(0)
    if r > 0:
        early = t + (v - 1.0) * t.square() / (2.0 * r)
        late = t + (v - 1.0) * (t - r / 2.0)
        tau = torch.where(t <= r, early, late)
        speed = 1.0 + (v - 1.0) * (t / r).clamp(max=1.0)
    else:
        tau, speed = v * t, v.expand(-1, length)
    return tau, speed


def warped_rows(starts: Tensor, context: int, length: int, factor: Tensor, ramp: int) -> tuple[Tensor, Tensor]:
    """Fractional rows ``[B, context + length]`` of windows starting at global rows ``starts [B]``:
    the context's own rows, then the warped transition's; and the replay speed per frame (1 in the context)."""
    tau, speed = warp_times(length, factor, ramp)
    base = starts.to(torch.float64).unsqueeze(1)
    ctx = base + torch.arange(context, dtype=torch.float64)
    rows = torch.cat([ctx, base + (context - 1) + tau], dim=1)
    return rows, torch.cat([torch.ones(len(starts), context, dtype=torch.float64), speed], dim=1)


def source_span(context: int, length: int, max_factor: float) -> int:
    """Capture frames a window of ``context + length`` frames warped by at most ``max_factor`` reads."""
    return context + math.ceil(max_factor * length) + 1


def draw_factors(n: int, max_factor: float, gen: torch.Generator) -> Tensor:
    """``n`` factors drawn log-uniformly in ``[1 / max_factor, max_factor]``."""
    if not 1.0 <= max_factor <= MAX_FACTOR:
        raise ValueError(f"the largest warp factor must be in [1, {MAX_FACTOR:g}], got {max_factor}")
    u = 2.0 * torch.rand(n, generator=gen, dtype=torch.float64) - 1.0
    return torch.exp(u * math.log(max_factor))

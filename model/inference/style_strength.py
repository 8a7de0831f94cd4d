"""Style strength: a style's context moved away from the bundle's neutral style (strength above 1) or toward it
(below 1; 0 is the neutral style itself).

The neutral style is the mean of the bundle's built-in styles' contexts (FiLM scales and shifts, and the
attention keys and values averaged over their real time steps too, so that it fits a code of any length). A
context at strength ``k`` is ``neutral + k * (context - neutral)`` field by field. It is applied where the
contexts of a batch are stacked (:mod:`model.inference.character_batch`), so registered, built-in and
several-clip styles all follow it, and cached styles stay as encoded.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import torch

from model.inference.declared_settings import BY_NAME

Tensor = torch.Tensor


def check_strength(strength: float) -> float:
    """``strength`` as a float in the declared range of ``style_strength`` ([0, 4]), else a ValueError."""
    value = float(strength)
    BY_NAME["style_strength"].check(value)
    return value


@dataclass(frozen=True)
class NeutralStyle:
    """The neutral style of a set of contexts, as a context whose fields broadcast over any batch and code length:
    each field's mean over the batch, and over the real time steps (its ``mask``) where the field has a time axis
    (the network's ``TIME_AXES``: for RSMT's, ``[1, width]`` for the FiLM fields, ``[1, width, 1]`` for keys and
    ``[1, 1, width]`` for values); its mask is one real step."""

    context: Any

    @classmethod
    def of(cls, contexts: list[Any]) -> NeutralStyle:
        """The neutral style of ``contexts`` (at least one; each a batch of one or more styles)."""
        if not contexts:
            raise ValueError("a neutral style needs at least one style context")
        kind = type(contexts[0])
        ctx = kind.stack(contexts)
        real = ctx.mask.float()  # [B, T']
        steps = real.sum()

        def mean(name: str) -> Tensor:
            t = getattr(ctx, name)
            axis = kind.TIME_AXES.get(name)
            if axis is None:
                return t.mean(0, keepdim=True)
            return (t * real.unsqueeze(3 - axis)).sum((0, axis), keepdim=True) / steps  # [B, T', w] or [B, w, T']

        scaled = {f.name: mean(f.name) for f in fields(ctx) if f.name != "mask"}
        return cls(kind(**scaled, mask=torch.ones(1, 1, dtype=torch.bool)))

    def scaled(self, ctx: Any, strength: float) -> Any:
        """``ctx`` at ``strength`` (1: ``ctx`` itself, the same object); its mask is kept."""
        if strength == 1.0:
            return ctx
        out = {f.name: getattr(ctx, f.name) for f in fields(ctx)}
        for name in out:
            if name != "mask":
                neutral = getattr(self.context, name)
                out[name] = neutral + strength * (out[name] - neutral)
        return type(ctx)(**out)

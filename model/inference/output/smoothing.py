"""A causal smoothing filter on the frames the engine emits.

The sampler's frames carry more 5-15 Hz jitter than captured motion (measured on the default
model: the 40-frame transitions' velocity power there is well above the capture's). A style
classifier, and a viewer, read that jitter as energy: an elderly walk looks brisk. One-pole
smoothing of what is emitted (each frame moved part of the way back towards the previous emitted
frame) removes most of it. It is causal, so streaming is unchanged, and costs one blend per frame.

The network keeps stepping on its own unfiltered state, so the filter never feeds back into the
recurrence. Its weight fades to 0 over the last ``fade`` frames, so the arrival frame is the
network's own and the filter's lag (``a / (1 - a)`` frames) is gone by the time the target is
reached. The first frame blends with the last context frame, so the seam stays continuous.

Letting the lag go speeds the root up: a root moving at ``v`` trails its network by ``a v / (1 - a)``,
made up over the last frames on top of ``v``. So a character with a speed cap (its style's capture maximum,
:mod:`model.inference.output.speed_cap`; a batch column this step reads) never has its root's ground step made
longer than that cap here (:func:`within_cap`): where the lag cannot be made up within it, the root arrives
that much late. A character without a cap is filtered as above.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from model.inference.output.frame import Frame, StepParts
from model.motion.rotations import quat_normalize

Tensor = torch.Tensor

DEFAULT_FADE = 5
SPEED_CAP = "speed_cap"  # the batch column of a character's speed cap (cm a frame on the ground; inf: none)


def smoothing_weight(strength: float, remaining: Tensor, fade: int = DEFAULT_FADE) -> Tensor:
    """Weight of the previous emitted frame for frames with ``remaining [N]`` frames after them."""
    if fade < 1:
        return torch.full(remaining.shape, float(strength))
    return strength * (remaining.float() / fade).clamp(0.0, 1.0)


def within_cap(root: Tensor, previous: Tensor, cap: Tensor) -> Tensor:
    """``root [N, 3]`` (emitted after ``previous``) with its ground step from ``previous`` no longer than ``cap [N]``
    (cm; ``inf``: as it is); its height as it is."""
    step = root - previous
    length = step[:, ::2].norm(dim=-1)
    over = length > cap
    scale = torch.where(over, cap / length.clamp_min(1e-6), torch.ones_like(length)).unsqueeze(-1)
    ground = torch.tensor([1.0, 0.0, 1.0], dtype=root.dtype)
    return torch.where(over.unsqueeze(-1), previous + step * (ground * scale + (1.0 - ground)), root)  # bits kept


def smooth_frame(rotations: Tensor, roots: Tensor, previous_rotations: Tensor, previous_roots: Tensor,
                 weight: Tensor, root_weight: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Blend a frame towards the previous emitted one by ``weight [N]`` (0: the frame as it is); the
    root by ``root_weight [N]`` (None: ``weight``).

    Args:
        rotations, previous_rotations: ``[N, J, 4]`` unit quaternions (local or global: the blend
            is per joint, so either works).
        roots, previous_roots: ``[N, 3]`` root positions.
    """
    w = weight.to(rotations.dtype).view(-1, 1)
    # The previous frame's quaternions on this frame's hemisphere, so the blend takes the short way.
    sign = torch.where((rotations * previous_rotations).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    rot = quat_normalize(torch.lerp(rotations, sign * previous_rotations, w.unsqueeze(-1)))
    wr = w if root_weight is None else root_weight.to(roots.dtype).view(-1, 1)
    return rot, torch.lerp(roots, previous_roots, wr)


class Smoothing:
    """The filter as a frame step (:mod:`model.inference.output.frame`): its memory is the previous emitted
    frame, remembered before the later steps (and exact arrival) bend it, so the filter follows the network."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = ("prev_rot", "prev_root")
    COLUMNS: ClassVar[tuple[str, ...]] = (SPEED_CAP,)

    def __init__(self, strength: float, root_strength: float) -> None:
        self.strength, self.root_strength = strength, root_strength

    @classmethod
    def build(cls, parts: StepParts) -> Smoothing | None:
        out = parts.settings
        return cls(out.smoothing, out.root_strength) if out.smooths else None

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        """The last context frame: the first generated frame blends with it, so the seam stays continuous."""
        return {"prev_rot": rotations[-1:], "prev_root": roots[-1:]}

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None:
        fade = smoothing_weight(1.0, frame.remaining)
        frame.local, root = smooth_frame(frame.local, frame.root, memory["prev_rot"], memory["prev_root"],
                                         self.strength * fade, self.root_strength * fade)
        frame.root = within_cap(root, memory["prev_root"], memory[SPEED_CAP])
        new["prev_rot"], new["prev_root"] = frame.local, frame.root

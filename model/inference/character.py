"""What the engine hands around: an encoded style, a weight set, one character's transition in progress,
and the poses of a batch step (:mod:`model.inference.engine` runs them)."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from model.inference.arrival import ArrivalState
from model.inference.traced_step import CompiledStep
from model.motion.features import CanonicalFrame
from model.nets.pose_state import PoseState
from model.nets.sampler import SamplerState, StyleContext, TransitionSampler

Tensor = torch.Tensor


@dataclass
class EncodedStyle:
    """A style clip encoded once: its id (content hash), name, length and per-frame context."""

    style_id: str
    name: str
    frames: int
    context: StyleContext
    nbytes: int = 0
    weights: str = ""  # the weight set it was encoded by and runs on: the bundle's own, or an adapter's name


@dataclass(eq=False)
class WeightSet:
    """One set of the sampler's weights the engine serves: the bundle's own (name ``""``) or a style
    adapter's (:mod:`model.inference.bundle_adapters`), with its per-frame step and version."""

    name: str
    sampler: TransitionSampler
    step_fn: CompiledStep
    version: str


@dataclass(eq=False)  # identity, not field equality: characters are looked up in batches
class Character:
    """One transition in progress. The engine's batch owns its tensors while it is live."""

    id: str
    style: EncodedStyle
    frames_total: int
    seq: int = 0  # frames emitted so far
    cancelled: bool = False
    slot: int = 0
    retargeted: bool = False  # given a new target mid-stream (its facing is finished by the retarget window)
    _row: SamplerState | None = field(default=None, repr=False)
    _frame: CanonicalFrame | None = field(default=None, repr=False)
    # Exact arrival (see model.inference.arrival): its per-character state and the target pose in world space.
    arrival: ArrivalState | None = None
    _target_pose: tuple[Tensor, Tensor] | None = field(default=None, repr=False)
    # Memory of the output steps (smoothing, foot lock) while out of a batch: named rows [1, ...].
    _post: dict[str, Tensor] | None = field(default=None, repr=False)
    # Inputs of the recurrent warm-up, run batched when the character joins a batch.
    _init: tuple[PoseState, PoseState, int, Tensor, bool] | None = field(default=None, repr=False)

    @property
    def remaining(self) -> int:
        return self.frames_total - self.seq

    @property
    def done(self) -> bool:
        return self.cancelled or self.seq >= self.frames_total


@dataclass
class StepOutput:
    """Poses of every character advanced by one :meth:`CharacterBatch.step`.

    ``rotations [N, J, 4]`` local quaternions and ``root_positions [N, 3]`` in world space, row
    ``i`` for ``characters[i]``; ``seq[i]`` is that frame's index within its transition.
    """

    characters: list[Character]
    rotations: Tensor
    root_positions: Tensor
    seq: list[int]

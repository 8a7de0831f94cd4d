"""What the engine hands around: an encoded style, a weight set, one character's transition in progress,
and the poses of a batch step (:mod:`model.inference.engine` runs them)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from model.inference.output.arrival import ArrivalMemory
from model.inference.reach import Reach
from model.inference.traced_step import CompiledStep
from model.motion.features import CanonicalFrame
from model.nets.pose_state import PoseState
from model.nets.transition_net import NetState, TransitionNet

Tensor = torch.Tensor


@dataclass
class EncodedStyle:
    """A style clip encoded once: its id (content hash), name, length and per-frame context."""

    style_id: str
    name: str
    frames: int
    context: Any  # the network's style context (model.nets.transition_net.StyleRecord)
    nbytes: int = 0
    weights: str = ""  # the weight set it was encoded by and runs on: the bundle's own, or an adapter's name
    clips: int = 1  # the clips it was encoded from (:mod:`model.inference.style_sets`); ``frames`` is their total
    gait: str = ""  # the built-in style whose capture limits it moves within ("": the largest of them all)


@dataclass(eq=False)
class WeightSet:
    """One set of the network's weights the engine serves: the bundle's own (name ``""``) or a style
    adapter's (:mod:`model.inference.bundle_adapters`), with its per-frame step and version."""

    name: str
    net: TransitionNet
    step_fn: CompiledStep
    version: str


@dataclass(frozen=True)
class PreparedStart:
    """What :meth:`Engine.prepare` leaves for the recurrent warm-up, run batched when the character joins a
    batch (:meth:`Engine.begin`): the context's and the target's states in the transition's frame, its
    length, its noise ``[1, 2W]``, and whether the target's velocity is known."""

    context: PoseState
    target: PoseState
    frames: int
    noise: Tensor
    velocity_known: bool


@dataclass(eq=False)  # identity, not field equality: characters are looked up in batches
class Character:
    """One transition in progress. The engine's batch owns its tensors while it is live: out of a batch,
    the character holds them itself (``row``, ``frame``, ``memory``), and before its first frame it holds
    what its warm-up needs (``prepared``)."""

    id: str
    style: EncodedStyle
    frames_total: int
    seq: int = 0  # frames emitted so far
    cancelled: bool = False
    slot: int = 0
    retargeted: bool = False  # given a new target mid-stream (its facing is finished by the retarget window)
    style_strength: float | None = None  # the strength its style runs at (model.inference.style_strength; None: the engine's)
    row: NetState | None = field(default=None, repr=False)  # its network state while out of a batch
    frame: CanonicalFrame | None = field(default=None, repr=False)  # its transition's frame, fixed when it starts
    # Exact arrival (see model.inference.output.arrival): the target pose in world space and its state.
    arrival: ArrivalMemory | None = None
    # Memory of the output pipeline's frame steps while out of a batch: named rows [1, ...].
    memory: dict[str, Tensor] | None = field(default=None, repr=False)
    prepared: PreparedStart | None = field(default=None, repr=False)
    # The most its root moves on the ground in a frame (cm; its style's capture maximum, inf: not capped), and
    # whether its target is within that reach (model.inference.reach; None: the bundle has no gait limits).
    speed_cap: float = math.inf
    reach: Reach | None = None
    # Its target's state in its canonical frame and whether its velocity is known, as asked (the network may aim
    # nearer where it is out of reach: model.inference.engine.Engine._limit).
    goal: tuple[PoseState, bool] | None = field(default=None, repr=False)

    def replica(self, character_id: str, style: EncodedStyle | None = None) -> Character:
        """Another character in this one's place (its prepared start or its state shared, never mutated by
        a batch, which copies what it joins), e.g. for warming a batch of many up."""
        return replace(self, id=character_id, style=self.style if style is None else style, seq=0, cancelled=False)

    def canonical_frame(self) -> CanonicalFrame:
        """:attr:`frame`, which every prepared character has."""
        if self.frame is None:
            raise ValueError("character was not prepared by Engine.prepare")
        return self.frame

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

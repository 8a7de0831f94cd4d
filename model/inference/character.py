"""What the engine hands around: an encoded style, a weight set, one character's transition in progress,
and the poses of a batch step (:mod:`model.inference.engine` runs them)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from model.inference.output.arrival import ArrivalMemory
from model.inference.output.steering import RETARGETED
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


@dataclass(frozen=True)
class Limits:
    """A character's caps from its style's capture (:mod:`model.motion.gait_limits`; inf: none), under the names of
    the batch columns the output steps read them by: the most its root moves on the ground in a frame (cm;
    :mod:`model.inference.output.speed_cap`, smoothing's root), its feet's lift off its floor (floor contact) and
    its planted feet's rise (the foot plant), in cm."""

    speed_cap: float = math.inf
    lift_cap: float = math.inf
    plant_cap: float = math.inf


@dataclass(frozen=True)
class CharacterRequest:
    """What the caller asked of one transition: its id, style (run at ``style_strength``,
    :mod:`model.inference.style_strength`; None: the engine's setting), its length in frames all told, and whether
    it was retargeted mid-stream (its facing is finished by the retarget window). Frozen: a retarget or a style
    switch makes a new one (``dataclasses.replace``) and hands it to the batch (:meth:`CharacterBatch.restate`)."""

    id: str
    style: EncodedStyle
    frames: int
    style_strength: float | None = None
    retargeted: bool = False


@dataclass(eq=False)  # identity, not field equality: characters are looked up in batches
class Character:
    """A handle on one transition in progress: its :class:`CharacterRequest`, its caps (:class:`Limits`, from its
    style), the frames emitted so far, and its live part. While it is a member of a batch the batch owns that part
    (its network row, canonical frame rows, output memory, style context and columns) and hands it back when it
    leaves (``row``, ``frame``, ``memory``); before its first frame it holds what its warm-up needs (``prepared``).
    The engine keeps its target (``goal``, ``arrival``) and its reach notice."""

    request: CharacterRequest
    limits: Limits = Limits()
    seq: int = 0  # frames emitted so far
    cancelled: bool = False
    slot: int = 0
    row: NetState | None = field(default=None, repr=False)  # its network state while out of a batch
    frame: CanonicalFrame | None = field(default=None, repr=False)  # its transition's frame, fixed when it starts
    # Exact arrival (see model.inference.output.arrival): the target pose in world space and its state.
    arrival: ArrivalMemory | None = None
    # Memory of the output pipeline's frame steps while out of a batch: named rows [1, ...].
    memory: dict[str, Tensor] | None = field(default=None, repr=False)
    prepared: PreparedStart | None = field(default=None, repr=False)
    # Whether its target is within its reach (model.inference.reach; None: the bundle has no gait limits).
    reach: Reach | None = None
    # Its target's state in its canonical frame and whether its velocity is known, as asked (the network may aim
    # nearer where it is out of reach: model.inference.engine.Engine.retarget).
    goal: tuple[PoseState, bool] | None = field(default=None, repr=False)

    @property
    def id(self) -> str:
        return self.request.id

    @property
    def style(self) -> EncodedStyle:
        return self.request.style

    @property
    def frames_total(self) -> int:
        return self.request.frames

    @property
    def style_strength(self) -> float | None:
        return self.request.style_strength

    @property
    def retargeted(self) -> bool:
        return self.request.retargeted

    def replica(self, character_id: str, style: EncodedStyle | None = None) -> Character:
        """Another character in this one's place (its prepared start or its state shared, never mutated by
        a batch, which copies what it joins), e.g. for warming a batch of many up."""
        request = replace(self.request, id=character_id, style=self.style if style is None else style)
        return replace(self, request=request, seq=0, cancelled=False)

    def canonical_frame(self) -> CanonicalFrame:
        """:attr:`frame`, which every prepared character has."""
        if self.frame is None:
            raise ValueError("character was not prepared by Engine.prepare")
        return self.frame

    def update_row(self, updates: dict[str, Tensor]) -> None:
        """Set fields of the network row it holds out of a batch (``updates``: name -> ``[1, ...]``; a batch's member
        is changed through :meth:`CharacterBatch.update_row`)."""
        if self.row is None:
            raise ValueError(f"character {self.id!r} holds no row: it has not begun, or a batch holds it")
        for name, value in updates.items():
            setattr(self.row, name, value)

    def column(self, name: str) -> float | bool:
        """Its value in the batch column ``name`` (a step's declared input): one of its :class:`Limits`, or whether
        it was retargeted."""
        return self.retargeted if name == RETARGETED else float(getattr(self.limits, name))

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

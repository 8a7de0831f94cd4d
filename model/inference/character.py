"""What the engine hands around: an encoded style, a weight set, one character's transition in progress,
and the poses of a batch step (:mod:`model.inference.engine` runs them)."""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from model.inference.controls import Controls
from model.inference.output.arrival import ArrivalPose, ArrivalState
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
    """What the caller asked of one transition: its id, style, its length in frames all told, whether it was
    retargeted mid-stream (its facing is finished by the retarget window), and the settings it set for itself
    (:class:`~model.inference.controls.Controls`, read by the engine step each belongs to). Frozen: a retarget or a
    style switch makes a new one (``dataclasses.replace``) and hands it to the batch
    (:meth:`CharacterBatch.restate`)."""

    id: str
    style: EncodedStyle
    frames: int
    retargeted: bool = False
    controls: Controls = Controls()


@dataclass(frozen=True)
class Parked:
    """A character's live part while no batch holds it (before it first joins one, or detached from one): its
    canonical frame (fixed when it starts), its output steps' memory (named rows ``[1, ...]``), exact arrival's
    memory, and its network row, or before its first frame what its warm-up needs (:class:`PreparedStart`). A batch
    takes it whole when the character joins (:meth:`CharacterBatch.admit`) and gives it back whole on
    :meth:`CharacterBatch.detach`; out of a batch only :meth:`Engine.begin`'s row and :meth:`Character.update_row`
    replace it, never change it (a replica may share it)."""

    frame: CanonicalFrame
    memory: dict[str, Tensor] = field(repr=False)
    state: NetState | PreparedStart = field(repr=False)
    arrival: ArrivalState = field(default_factory=ArrivalState, repr=False)  # copied by the batch that takes it

    @property
    def row(self) -> NetState | None:
        """Its network row; None before it has begun."""
        return None if isinstance(self.state, PreparedStart) else self.state

    @property
    def prepared(self) -> PreparedStart | None:
        """What its warm-up needs; None once it has begun."""
        return self.state if isinstance(self.state, PreparedStart) else None


@dataclass(frozen=True)
class Aim:
    """The engine's view of a character's target, built whole by :meth:`Engine.prepare` and :meth:`Engine.retarget`:
    its state in the character's canonical frame and whether its velocity is known, as asked (the network may aim
    nearer where it is out of reach), its reach notice (:mod:`model.inference.reach`; None: the bundle has no gait
    limits) and, with exact arrival, the pose it arrives at (:mod:`model.inference.output.arrival`)."""

    goal: PoseState = field(repr=False)
    velocity_known: bool
    reach: Reach | None = None
    arrival: ArrivalPose | None = field(default=None, repr=False)

    @property
    def bent_to(self) -> ArrivalPose | None:
        """The pose exact arrival bends its last frames onto: none where its target is out of reach, so it arrives
        short rather than be dragged onto the target faster than its style walks."""
        return self.arrival if self.reach is None or self.reach.feasible else None


@dataclass(eq=False)  # identity, not field equality: characters are looked up in batches
class Character:
    """A handle on one transition in progress: its :class:`CharacterRequest`, the engine's :class:`Aim`, its caps
    (:class:`Limits`, from its style), the frames emitted so far, and its live part (:class:`Parked`) while no batch
    holds it: a batch takes that whole when the character joins (``parked`` is None then) and hands it back whole
    when it leaves."""

    request: CharacterRequest
    aim: Aim
    limits: Limits = Limits()
    seq: int = 0  # frames emitted so far
    cancelled: bool = False
    slot: int = 0
    parked: Parked | None = None

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
    def retargeted(self) -> bool:
        return self.request.retargeted

    @property
    def reach(self) -> Reach | None:
        """Whether its target is within its reach (:attr:`Aim.reach`)."""
        return self.aim.reach

    @property
    def arrival(self) -> ArrivalPose | None:
        """The pose it arrives at exactly (:attr:`Aim.arrival`; None: the network's own arrival)."""
        return self.aim.arrival

    def replica(self, character_id: str, style: EncodedStyle | None = None) -> Character:
        """Another character in this one's place (its :class:`Parked` part shared: a batch copies what it takes),
        e.g. for warming a batch of many up."""
        request = replace(self.request, id=character_id, style=self.style if style is None else style)
        return replace(self, request=request, seq=0, cancelled=False)

    def update_row(self, updates: dict[str, Tensor]) -> None:
        """Set fields of the network row it holds out of a batch (``updates``: name -> ``[1, ...]``; a batch's member
        is changed through :meth:`CharacterBatch.update_row`): a new row in a new :class:`Parked`, the old ones as
        they were."""
        row = None if self.parked is None else self.parked.row
        if self.parked is None or row is None:
            raise ValueError(f"character {self.id!r} holds no row: it has not begun, or a batch holds it")
        row = copy.copy(row)
        for name, value in updates.items():
            setattr(row, name, value)
        self.parked = replace(self.parked, state=row)

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

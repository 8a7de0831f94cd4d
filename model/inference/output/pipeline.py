"""The output pipeline: every step a generated frame goes through before it leaves, in the order they run.

:data:`STEPS` is the list. Most steps run on the whole batch's frame, in one traced graph
(``FRAME``: :class:`FrameSteps`, traced by :mod:`model.inference.traced_step`); steering runs inside
the recurrent step (``LOOP``: it moves the sampler's own state, so the next step sees it), then the
speed cap (``LOOP`` too, per character: its style's capture speed), and exact arrival after the graph,
on the rows that asked for it (``AFTER``). Each step's module owns its
settings, its per-character memory and its start, and names the per-character inputs it reads (its columns:
a frame step's ``COLUMNS``, a loop step's here), which the batch stacks from its members
(:mod:`model.inference.character_batch`; :mod:`model.inference.output.frame` says what a frame step is). To add a
step: write its module, and add its line here.

Every step is causal and per character, so whole transitions and streams get the same frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import torch

from model.inference.output.arrival import ArrivalCorrector, ExactArrival
from model.inference.output.floor_contact import FloorStep
from model.inference.output.foot_lock import FootLockStep
from model.inference.output.foot_plant import FootPlantStep
from model.inference.output.frame import Frame, FrameStep, StepParts
from model.inference.output.settings import OutputConfig
from model.inference.output.smoothing import SPEED_CAP, Smoothing
from model.inference.output.speed_cap import speed_capped
from model.inference.output.steering import RETARGETED, SteeringConfig
from model.inference.output.stride_warp import StrideWarpStep
from model.motion.skeleton import Skeleton
from model.nets.pose_state import PoseState

Tensor = torch.Tensor
Where = Literal["loop", "frame", "after"]


@dataclass(frozen=True)
class Step:
    """One line of :data:`STEPS`: its name, where it runs, how it is built for a bundle's settings (None: off), and
    for a loop step the batch columns it reads (a frame step names its own: ``COLUMNS``)."""

    name: str
    where: Where
    build: Callable[[StepParts], Any]
    columns: tuple[str, ...] = ()


STEPS: tuple[Step, ...] = (
    # In CompiledStep (model.inference.traced_step); the rows retargeted mid-stream take the retarget window.
    Step("steering", "loop", lambda parts: parts.settings.steering, (RETARGETED,)),
    # Per character, its style's capture speed: in CharacterBatch.step (model.inference.character_batch).
    Step("speed_cap", "loop", lambda parts: speed_capped, (SPEED_CAP,)),
    Step("smoothing", "frame", Smoothing.build),  # to world space first: Frame
    Step("floor_contact", "frame", FloorStep.build),
    Step("stride_warp", "frame", StrideWarpStep.build),
    Step("foot_lock", "frame", FootLockStep.build),
    Step("foot_plant", "frame", FootPlantStep.build),  # last of the feet: on the floor, whatever moved them
    Step("exact_arrival", "after", lambda parts: ExactArrival(ArrivalCorrector(parts.skeleton))),  # per request
)


class FrameSteps:
    """The ``frame`` steps of :data:`STEPS` that a bundle's settings switch on, run in order on one frame.

    Each character's memory is a dict of named rows ``[N, ...]`` (:attr:`memory_keys`: each step's, in order);
    the steps' columns (:attr:`columns`, inputs the batch stacks from its members) come in the same dict.
    :attr:`keys` is both, step by step, in the order the traced graph and the ONNX export take and return them
    (a column comes back as it went in). Eager and traced paths share this code.
    """

    def __init__(self, skeleton: Skeleton, steps: dict[str, FrameStep]) -> None:
        self.parents, self.root = list(skeleton.parents), skeleton.roles.root
        self.steps = steps
        self.memory_keys: tuple[str, ...] = tuple(k for step in steps.values() for k in step.MEMORY_KEYS)
        self.columns: tuple[str, ...] = tuple(k for step in steps.values() for k in step.COLUMNS)
        self.keys: tuple[str, ...] = tuple(k for step in steps.values() for k in (*step.MEMORY_KEYS, *step.COLUMNS))

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        """One character's memory of every step, from its context ``[T, J, 4]`` (unit quaternions), ``[T, 3]``."""
        memory: dict[str, Tensor] = {}
        for step in self.steps.values():
            memory.update(step.start(rotations, roots))
        return memory

    def open_columns(self) -> dict[str, Tensor]:
        """Every column of one character that has no caps (``[1]`` each, inf)."""
        return {k: torch.full((1,), math.inf) for k in self.columns}

    def __call__(self, pose: PoseState, yaw: Tensor, origin: Tensor, remaining: Tensor, memory: dict[str, Tensor],
                 eager: bool = True, shift: Tensor | None = None) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Local rotations ``[N, J, 4]``, root positions ``[N, 3]`` (world) and the new memory, for rows with
        ``remaining [N]`` frames after this one; ``shift [N, 2]``: the ground shift steering gave each row's
        body this frame (canonical x, z; :mod:`model.inference.output.steering`)."""
        frame = Frame(pose, yaw, origin, remaining, shift, self.parents, self.root, eager)
        new: dict[str, Tensor] = {}
        for step in self.steps.values():
            step(frame, memory, new)
        new.update({k: memory[k] for k in self.columns})  # as they came in
        return frame.local, frame.root, new


class OutputPipeline:
    """:data:`STEPS` built for one skeleton, fps and output settings: steering's settings for the recurrent
    step, the frame steps, and exact arrival."""

    def __init__(self, skeleton: Skeleton, fps: float, settings: OutputConfig) -> None:
        parts = StepParts(skeleton, fps, settings)
        built = {s.name: (s.where, s.build(parts)) for s in STEPS}
        self.settings = settings
        self.loop_columns = tuple(k for s in STEPS if s.where == "loop" for k in s.columns)
        self.steering: SteeringConfig = built["steering"][1]
        self.arrival: ExactArrival = built["exact_arrival"][1]
        self.frame = FrameSteps(skeleton, {name: step for name, (where, step) in built.items()
                                           if where == "frame" and step is not None})

    def step(self, name: str) -> FrameStep | None:
        """The frame step ``name`` of :data:`STEPS`, or None where these settings switch it off."""
        return self.frame.steps.get(name)

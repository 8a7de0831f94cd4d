"""What the frame steps share: the frame of a batch on its way out, and what a step is built from.

A frame step (:mod:`model.inference.output.pipeline` lists them) is a class with

* ``MEMORY_KEYS``: the names of its per-character memory rows (``[N, ...]`` each, kept by the batch);
* ``COLUMNS``: the names of the per-character inputs it reads (``[N]`` each: its caps, inf where a character has
  none), which the batch stacks from its members (:class:`model.inference.character.Limits`) and hands in beside
  the memory; a step reads them and never writes them;
* ``build(parts) -> step | None``: the step for a bundle's settings, None where they switch it off;
* ``start(rotations, roots) -> memory``: one character's memory from its context ``[T, J, 4]``, ``[T, 3]``;
* ``__call__(frame, memory, new)``: change the :class:`Frame` in place, reading its memory and columns from
  ``memory`` and writing its memory into ``new``.

Steps run eagerly or inside one traced graph (:mod:`model.inference.traced_step`): they branch on settings,
never on the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import torch

from model.inference.output.leg_chains import LegChains
from model.inference.output.settings import OutputConfig
from model.motion.features import CanonicalFrame
from model.motion.kinematics import ChainKinematics, feet_kinematics, global_to_local_rotations
from model.motion.rotations import sixd_to_quat
from model.motion.skeleton import Skeleton
from model.nets.pose_state import GROUND_TO_3D, PoseState

Tensor = torch.Tensor


@dataclass
class StepParts:
    """What a frame step is built from: the skeleton, its fps, the bundle's output settings (overrides
    applied), and the legs' kinematics every step that reads the legs shares, so the frame computes them once."""

    skeleton: Skeleton
    fps: float
    settings: OutputConfig
    kinematics: ChainKinematics = field(init=False)
    _legs: LegChains | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.kinematics = feet_kinematics(self.skeleton)

    @property
    def legs(self) -> LegChains:
        """Both legs as two-bone chains over :attr:`kinematics` (one object for every step that moves feet)."""
        if self._legs is None:
            self._legs = LegChains(self.skeleton, self.kinematics)
        return self._legs


def world_pose(pose: PoseState, frame: CanonicalFrame, parents: list[int], root: int) -> tuple[Tensor, Tensor]:
    """A generated pose (canonical frame) in world space: local quaternions ``[N, J, 4]`` and root
    positions ``[N, 3]``, for each row's :class:`CanonicalFrame` (``yaw [N]``, ``origin [N, 3]``)."""
    grot = frame.rotations_from(sixd_to_quat(pose.rot))
    root_pos = frame.positions_from(pose.rel[:, root] + pose.root_xz @ GROUND_TO_3D)  # pose.positions()[:, root]
    return global_to_local_rotations(grot, parents), root_pos


class Frame:
    """One frame of ``N`` characters as the steps hand it on: ``local [N, J, 4]`` rotations and ``root [N, 3]``
    (world), with what the steps before left for the ones after.

    ``pose``: the network's pose (canonical frame, steering included); ``remaining [N]``: frames after this
    one (0 on arrival); ``shift [N, 2]``: the ground shift steering gave each body this frame (canonical x, z;
    None: not steered); ``eager``: run eagerly, where a step may skip work the data does not need (a traced
    graph keeps every operation). ``chains``: the legs' kinematics of the frame as it stands, where a step computed
    them (by ``chains_by``: a step reads them only where it reads the legs through the same object);
    ``ankle_moves [N, 2, 3]``: where the stride warp moves the ankles, for the foot lock to reach.
    """

    def __init__(self, pose: PoseState, yaw: Tensor, origin: Tensor, remaining: Tensor, shift: Tensor | None,
                 parents: list[int], root: int, eager: bool = True) -> None:
        self.eager = eager
        self.pose, self.yaw, self.origin, self.remaining, self.shift, self.root_joint = (
            pose, yaw, origin, remaining, shift, root)
        self.world = CanonicalFrame(yaw, origin)  # each row's
        self.local, self.root = world_pose(pose, self.world, parents, root)
        self.chains: tuple[Tensor, Tensor] | None = None
        self.chains_by: ChainKinematics | None = None
        self.ankle_moves: Tensor | None = None
        self._world_shift: Tensor | None = None

    def world_shift(self) -> Tensor | None:
        """Steering's shift this frame in the world ``[N, 3]`` (what of it is left for the steps after, once a
        step took part of it up: :meth:`leave_shift`); None when not steered."""
        if self._world_shift is None and self.shift is not None:
            self._world_shift = self.world.vectors_from(self.shift @ GROUND_TO_3D)
        return self._world_shift

    def chains_of(self, kinematics: ChainKinematics) -> tuple[Tensor, Tensor] | None:
        """:attr:`chains` where ``kinematics`` computed them, else None."""
        return self.chains if self.chains_by is kinematics else None

    def set_chains(self, kinematics: ChainKinematics, chains: tuple[Tensor, Tensor] | None) -> None:
        """The legs' kinematics of the frame as it now stands (None: none known, e.g. once the legs were bent)."""
        self.chains, self.chains_by = chains, kinematics

    def leave_shift(self, left: Tensor) -> None:
        """What a step left of steering's shift ``[N, 3]`` (world) for the steps after it."""
        self._world_shift = left


class FrameStep(Protocol):
    """A step of the frame output (see the module doc)."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]]
    COLUMNS: ClassVar[tuple[str, ...]]

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]: ...

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None: ...

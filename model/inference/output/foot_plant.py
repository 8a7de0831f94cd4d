"""Foot plant: a planted foot stands on the floor, however little the network learnt to put it there.

A network trained briefly (a user's first run on their own rig) plants feet in the air: the foot stops
over the ground and hovers, or rises while it stands. Floor contact (:mod:`model.inference.output.floor_contact`)
keeps the lowest foot of a body on its floor, not the other one; the foot lock holds a foot only where it
touched down near the ground. Here, last of the steps that move feet, each frame, a foot that stands still
as it leaves (its ankle's ground speed, :mod:`model.motion.planted_feet`: smoothly between planted and free)
and whose lowest joint stands more than its style's capture allows above the floor (``planted_rise_cm`` of
:mod:`model.motion.gait_limits`, kept in this step's memory and set by the engine) is brought down that far
by two-bone IK on its leg (:mod:`model.inference.output.leg_chains`), the foot keeping its world rotation.
Free feet and feet on the floor pass untouched; no foot is raised or moved over the ground. The floor is the
lowest any foot joint reaches in the character's context (as floor contact's); speeds are the outgoing
frames' (a foot that steering drags along is not planted). A character without a measured rise (``inf``: a
bundle without gait limits, or with ones measured before this step) is left as it is.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from model.inference.output.frame import Frame, StepParts
from model.inference.output.leg_chains import LegChains
from model.motion.planted_feet import planted_weight
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

PLANT_CAP = "plant_cap"  # the batch column of a character's planted rise (cm above its floor; inf: none)
_UP = torch.tensor([0.0, 1.0, 0.0])


class FootPlant:
    """Batched, for one skeleton's legs at ``fps``: how far to bring each planted foot down."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = ("plant_floor", "plant_previous")
    COLUMNS: ClassVar[tuple[str, ...]] = (PLANT_CAP,)

    def __init__(self, skeleton: Skeleton, fps: float, legs: LegChains) -> None:
        self.legs, self.fps = legs, fps
        self.feet = (list(skeleton.roles.left_foot), list(skeleton.roles.right_foot))
        self.legs.kinematics.columns(self.feet[0] + self.feet[1])  # a ValueError when it does not reach them

    def lowest(self, positions: Tensor) -> Tensor:
        """Each foot's lowest joint height ``[N, 2]`` in world ``positions [N, K, 3]`` of the legs' kinematics."""
        pick = self.legs.kinematics.pick
        return torch.stack([pick(positions, foot)[..., 1].amin(dim=-1) for foot in self.feet], dim=-1)

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        """One character's memory from its context ``[T, J, 4]``, ``[T, 3]``: its floor, its last ankles."""
        chains = self.legs.kinematics(rotations, roots)
        pos = self.legs.poses(rotations, roots, chains)[0]
        return {"plant_floor": self.lowest(chains[0]).min().view(1), "plant_previous": pos[-1:, -1].clone()}

    def drop(self, positions: Tensor, ankles: Tensor, memory: dict[str, Tensor]) -> Tensor:
        """How far ``[N, 2]`` to bring each foot down, for the legs' kinematics ``positions [N, K, 3]`` and the
        ankles ``[N, 2, 3]`` (world) of the frame, against the ankles of the frame before in ``memory``."""
        speed = (ankles - memory["plant_previous"])[..., ::2].norm(dim=-1) * self.fps  # x, z: moving down is not moving
        rise = self.lowest(positions) - memory["plant_floor"].unsqueeze(-1)
        excess = (rise - memory[PLANT_CAP].unsqueeze(-1)).clamp_min(0.0)  # inf cap: -inf, clamped to 0
        return excess * planted_weight(speed)


class FootPlantStep:
    """The foot plant as a frame step (:mod:`model.inference.output.frame`), after every step that moves the
    feet (floor contact, the stride warp, the foot lock): it reads the legs as they leave."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = FootPlant.MEMORY_KEYS
    COLUMNS: ClassVar[tuple[str, ...]] = FootPlant.COLUMNS

    def __init__(self, plant: FootPlant) -> None:
        self.plant = plant

    @classmethod
    def build(cls, parts: StepParts) -> FootPlantStep | None:
        return cls(FootPlant(parts.skeleton, parts.fps, parts.legs)) if parts.settings.foot_plant else None

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        return self.plant.start(rotations, roots)

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None:
        legs = self.plant.legs
        chains = legs.kinematics(frame.local, frame.root)  # the steps before may have bent the legs
        pos, grot = legs.poses(frame.local, frame.root, chains)
        ankles = pos[:, -1]
        down = self.plant.drop(chains[0], ankles, memory)
        move = down > 1e-4  # [N, 2]
        if not frame.eager or bool(move.any()):
            frame.local = legs.bend(frame.local, pos, grot, ankles - down.unsqueeze(-1) * _UP, move)
        frame.set_chains(legs.kinematics, None)
        new.update({"plant_floor": memory["plant_floor"], "plant_previous": ankles})

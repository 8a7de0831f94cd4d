"""Floor contact: keep the feet from sinking into the floor, by lifting the whole body.

The network's poses can sink: on the default model's walks to a target behind the character the
hips dropped 8-10 cm in the last frames and the toes went that far under the floor. Where the lowest
foot joint of a frame is more than ``tolerance_cm`` below the floor, the root (and so the whole
body) is raised by the difference; nothing else changes, and frames with the feet on or above the
floor pass untouched. The floor of a character is the lowest any foot joint reaches in its context,
so a game's own ground level is kept, whatever it is.

Nor may a body float: where every foot joint of a frame is more than the character's lift cap above its
floor (its style's capture: the most the lowest foot rose in any of its takes, a run's flight included;
:mod:`model.motion.gait_limits`, kept in this step's memory and set by the engine), the whole body is
lowered by the excess. A character without a cap (``inf``, a bundle without gait limits) is only lifted.
"""

from __future__ import annotations

from typing import ClassVar

import torch

from model.inference.output.frame import Frame, StepParts
from model.motion.kinematics import ChainKinematics, feet_kinematics
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor

TOLERANCE_CM = 1.0  # real feet dip a little under their resting height; only more than this is corrected
_UP = torch.tensor([0.0, 1.0, 0.0])
LIFT_CAP = "lift_cap"  # the batch column of a character's lift cap (cm above its floor; inf: none)


class FloorContact:
    """Batched, for one skeleton: the floor of a context and the lift of a frame (foot joints only)."""

    def __init__(self, skeleton: Skeleton, tolerance_cm: float = TOLERANCE_CM,
                 kinematics: ChainKinematics | None = None) -> None:
        """``kinematics``: the feet's chains (:func:`feet_kinematics`) to use, e.g. one the foot lock uses
        too, so that the frame output computes them once for both; by default its own."""
        if tolerance_cm < 0:
            raise ValueError(f"the floor tolerance must be 0 or more, got {tolerance_cm}")
        self.tolerance = tolerance_cm
        self.feet = list(skeleton.feet)
        self.kinematics = feet_kinematics(skeleton) if kinematics is None else kinematics
        self.kinematics.columns(self.feet)  # a ValueError when it does not reach every foot joint

    def foot_heights(self, rotations: Tensor, roots: Tensor) -> Tensor:
        """Heights ``[N, F]`` of the foot joints of local ``rotations [N, J, 4]`` and ``roots [N, 3]``."""
        return self.heights_of(self.kinematics(rotations, roots)[0])

    def heights_of(self, positions: Tensor) -> Tensor:
        """Heights ``[N, F]`` of the foot joints in world ``positions [N, K, 3]`` of :attr:`kinematics`' joints."""
        return self.kinematics.pick(positions, self.feet)[..., 1]

    def floor(self, rotations: Tensor, roots: Tensor) -> Tensor:
        """The floor ``[1]`` of one character's context ``[T, J, 4]``, ``[T, 3]``: its lowest foot joint."""
        return self.foot_heights(rotations, roots).min().view(1)

    def lift(self, rotations: Tensor, roots: Tensor, floor: Tensor) -> Tensor:
        """``roots [N, 3]`` raised so no foot joint is more than the tolerance under each row's ``floor [N]``."""
        return roots + self.lift_of(self.kinematics(rotations, roots)[0], floor)

    def lift_of(self, positions: Tensor, floor: Tensor, cap: Tensor | None = None) -> Tensor:
        """How far ``[N, 3]`` to raise bodies whose :attr:`kinematics` joints are at world ``positions [N, K, 3]``,
        so no foot joint is more than the tolerance under each row's ``floor [N]`` (and, with ``cap [N]``, to lower
        them so the lowest is at most ``cap`` above it)."""
        lowest = self.heights_of(positions).amin(dim=-1)
        up = (floor - self.tolerance - lowest).clamp_min(0.0)
        if cap is not None:
            up = up - (lowest - floor - cap).clamp_min(0.0)
        return up.unsqueeze(-1) * _UP  # (0, up, 0), in two operations rather than a stack of three parts


class FloorStep:
    """Floor contact as a frame step (:mod:`model.inference.output.frame`): its memory is the floor of the
    character's context. It runs before the feet are moved, so the feet the lock holds are where the body was
    lifted to; it leaves the lifted legs' kinematics on the frame (a lift moves every joint up alike)."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = ("floor",)
    COLUMNS: ClassVar[tuple[str, ...]] = (LIFT_CAP,)

    def __init__(self, contact: FloorContact) -> None:
        self.contact = contact

    @classmethod
    def build(cls, parts: StepParts) -> FloorStep | None:
        return cls(FloorContact(parts.skeleton, kinematics=parts.kinematics)) if parts.settings.floor else None

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        return {"floor": self.contact.floor(rotations, roots)}

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None:
        legs = self.contact.kinematics(frame.local, frame.root)
        up = self.contact.lift_of(legs[0], memory["floor"], memory[LIFT_CAP])
        frame.root = frame.root + up
        frame.set_chains(self.contact.kinematics, (legs[0] + up.unsqueeze(-2), legs[1]))
        new["floor"] = memory["floor"]

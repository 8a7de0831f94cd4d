"""Stride warping: longer (or shorter) strides where steering carries the body faster than the gait.

Steering (:mod:`model.inference.output.steering`) moves the whole body toward a target the network's gait
would not reach in time, so a foot the network plants is carried along and slides; the foot lock can
hold it only as far as the leg reaches. Engines meet the same problem (a capsule moving faster than
its animation) by placing the feet further from the hips along the motion. Here, each frame, with
``u`` the ground shift steering gave the body and ``v`` the network's own root velocity (its velocity
less the shift), each ankle moves on the ground by ``(r . v/|v|) u / |v|``, ``r`` being its ground
offset from the root. A planted foot's offset shrinks by ``|v|`` a frame, so its move changes by
``-u``: it stays where it is in the world while the body is carried, and a swinging foot lands
further along. The legs reach the moved ankles by two-bone IK (:mod:`model.inference.output.leg_chains`).

``|u| / |v|`` is capped at ``reach`` (the longest stride is ``1 + reach`` times the network's); the
warp fades in with the root's speed (none for a character standing or turning on the spot) and out
over the last ``fade`` frames, so the arrival frame is the network's own. The offsets are integrated
over the stride in each character's memory (each ankle's offset and its place along the motion last
frame), pulled a little each frame toward the offset the formula gives on its own; whole transitions
and streams step the same memory, so they get the same frames. What the cap leaves of the shift is
returned for the foot lock, which then judges planted feet against that part only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from model.inference.output.frame import Frame, StepParts
from model.inference.output.leg_chains import LegChains

Tensor = torch.Tensor

_GROUND = torch.tensor([1.0, 0.0, 1.0])  # keeps the x and z of a vector


@dataclass(frozen=True)
class StrideWarpConfig:
    reach: float  # cap on |shift| / |network root speed|: strides up to 1 + reach times the network's
    slow_cm_s: float = 15.0  # root speed under which nothing is warped
    full_cm_s: float = 45.0  # root speed from which the warp is whole
    fade: int = 5  # frames before arrival over which the warp fades out
    settle: float = 0.1  # share of the way a frame the integrated offset is pulled to the stateless one

    def __post_init__(self) -> None:
        if not 0.0 < self.reach <= 4.0:
            raise ValueError(f"stride warp reach must be in (0, 4], got {self.reach}")
        if not 0.0 <= self.slow_cm_s < self.full_cm_s:
            raise ValueError("stride warp needs 0 <= slow_cm_s < full_cm_s")
        if self.fade < 0:
            raise ValueError("stride warp fade must be 0 or more")
        if not 0.0 <= self.settle <= 1.0:
            raise ValueError("stride warp settle must be in [0, 1]")


class StrideWarp:
    """Batched stride warping for one skeleton (Y up, cm) at ``fps``, with per-character memory."""

    MEMORY_KEYS = ("warp_offset", "warp_along")

    def __init__(self, legs: LegChains, fps: float, config: StrideWarpConfig) -> None:
        self.legs, self.fps, self.config = legs, fps, config

    def ratio(self, shift: Tensor, speed: Tensor, remaining: Tensor) -> Tensor:
        """The ground shift per unit of root speed ``[N, 3]`` the warp takes up, for steering's ``shift
        [N, 3]``, the network's own ground ``speed [N, 1]`` (cm a frame, shift excluded) and ``remaining
        [N]`` frames after this one (0 on arrival)."""
        c = self.config
        ratio = shift * _GROUND / speed.clamp_min(1e-3)
        ratio = ratio * (c.reach / ratio.norm(dim=-1, keepdim=True).clamp_min(c.reach))
        x = ((speed * self.fps - c.slow_cm_s) / (c.full_cm_s - c.slow_cm_s)).clamp(0.0, 1.0)
        gate = x * x * (3.0 - 2.0 * x)
        if c.fade > 0:
            gate = gate * (remaining.float() / c.fade).clamp(0.0, 1.0).unsqueeze(-1)
        return ratio * gate

    def start(self, rows: int = 1) -> dict[str, Tensor]:
        """A character's warp memory under :attr:`MEMORY_KEYS`: no offset yet, no stride seen."""
        return {"warp_offset": torch.zeros(rows, 2, 3), "warp_along": torch.full((rows, 2), float("nan"))}

    def offsets(self, pos: Tensor, roots: Tensor, remaining: Tensor, velocity: Tensor, shift: Tensor,
                memory: dict[str, Tensor]) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """How far to move each ankle on the ground ``[N, 2, 3]``, the part of ``shift`` the warp left
        (``[N, 3]``, what still carries a planted foot) and the new memory, for legs at world positions
        ``pos`` (:meth:`LegChains.poses`); the arguments otherwise as :meth:`apply`'s."""
        c = self.config
        v = velocity * _GROUND
        speed = v.norm(dim=-1, keepdim=True)
        ratio = self.ratio(shift, speed, remaining)  # [N, 3]
        ank = pos[:, -1]  # [N, 2, 3]
        heading = v / speed.clamp_min(1e-3)
        along = ((ank - roots.unsqueeze(1)) * heading.unsqueeze(1)).sum(-1)  # [N, 2]
        last = memory["warp_along"]
        step = torch.where(torch.isnan(last), torch.zeros_like(along), along - last)  # no stride seen: no change
        grown = memory["warp_offset"] + step.unsqueeze(-1) * ratio.unsqueeze(1)
        settled = along.unsqueeze(-1) * ratio.unsqueeze(1)  # the stateless offset, which the state is pulled to
        offset = grown + c.settle * (settled - grown)
        if c.fade > 0:
            offset = offset * (remaining.float() / c.fade).clamp(0.0, 1.0).view(-1, 1, 1)
        return offset, shift - ratio * speed, {"warp_offset": offset, "warp_along": along}

    def apply(self, rotations: Tensor, roots: Tensor, remaining: Tensor, velocity: Tensor, shift: Tensor,
              memory: dict[str, Tensor], chains: tuple[Tensor, Tensor] | None = None
              ) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Warp the strides of one frame of ``N`` characters: new local rotations, the part of
        ``shift`` the warp left (``[N, 3]``) and the new memory. With the foot lock on, the frame
        warp step hands :meth:`offsets` to the lock instead, so both legs are solved once.

        Args:
            rotations, roots: ``[N, J, 4]`` local rotations and ``[N, 3]`` roots (world).
            remaining: ``[N]`` frames left after this one (0 on the arrival frame).
            velocity: ``[N, 3]`` the network's own root velocity this frame (world, cm a frame,
                steering's shift excluded).
            shift: ``[N, 3]`` how far steering moved the whole body this frame (world).
            memory: ``warp_offset [N, 2, 3]`` (each ankle's move last frame) and ``warp_along [N, 2]``
                (each ankle's ground offset from the root along the motion last frame; NaN: none).
            chains: the legs' kinematics results for these rotations and roots, where the caller has them.
        """
        pos, grot = self.legs.poses(rotations, roots, chains)
        offset, left, new = self.offsets(pos, roots, remaining, velocity, shift, memory)
        move = offset.norm(dim=-1) > 1e-4  # [N, 2]
        return self.legs.bend(rotations, pos, grot, pos[:, -1] + offset, move), left, new


class StrideWarpStep:
    """The stride warp as a frame step (:mod:`model.inference.output.frame`), on where steering's ground part
    is. With the foot lock after it, it leaves the ankles' moves to the lock (one IK reaches both); alone,
    it bends the legs itself. Either way it leaves the rest of steering's shift to the steps after it."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = StrideWarp.MEMORY_KEYS
    COLUMNS: ClassVar[tuple[str, ...]] = ()

    def __init__(self, warp: StrideWarp, lock_follows: bool) -> None:
        self.warp, self.lock_follows = warp, lock_follows

    @classmethod
    def build(cls, parts: StepParts) -> StrideWarpStep | None:
        out = parts.settings
        if out.stride_warp <= 0 or out.steering.window <= 0:
            return None
        return cls(StrideWarp(parts.legs, parts.fps, StrideWarpConfig(out.stride_warp)), out.foot_lock)

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        return self.warp.start()

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None:
        shift = frame.world_shift()
        if shift is None:  # not steered this frame: nothing to warp, the memory kept
            new.update({k: memory[k] for k in self.MEMORY_KEYS})
            return
        # The network's own root velocity: its state's, less the shift steering added to it.
        velocity = frame.world.vectors_from(frame.pose.vel[:, frame.root_joint]) - shift
        own = {k: memory[k] for k in self.MEMORY_KEYS}
        legs = self.warp.legs
        if self.lock_follows:
            chains = frame.chains_of(legs.kinematics)
            if chains is None:
                chains = legs.kinematics(frame.local, frame.root)
                frame.set_chains(legs.kinematics, chains)
            pos = legs.poses(frame.local, frame.root, chains)[0]
            frame.ankle_moves, left, warped = self.warp.offsets(pos, frame.root, frame.remaining, velocity, shift, own)
        else:  # its own legs' kinematics, as the warp has always computed them alone
            frame.local, left, warped = self.warp.apply(frame.local, frame.root, frame.remaining, velocity, shift, own)
            frame.set_chains(legs.kinematics, None)  # the legs were bent
        frame.leave_shift(left)
        new.update(warped)

"""Foot locking: hold a generated foot still while it is planted, by two-bone IK on its leg.

The sampler's planted feet creep: slowly enough to pass as contact, fast enough to read as skating
(the default model's foot skate was about 1.5x the capture's). Engines fix this with foot IK; the
service does it before frames leave, frame by frame, with explicit per-character state, so a
whole transition and a stream get the same frames.

A foot locks when its ankle is within ``contact_cm`` of the ground and moving slower than
``plant_speed_cm_s``; it is then held where it was (all three coordinates) by rotating the hip and
knee, the foot keeping its own world rotation. It lets go when the generated ankle lifts more than
``lift_cm`` above the ground or drifts ``release_cm`` away from the lock, and the held offset then
shrinks by ``catch_up`` each frame, so the foot rejoins the generated motion (in the air, for a
lift; a foot that drifted away locks again once within ``rejoin_cm`` of the generated one). The
ground is the lowest ankle height of the context. Over the last ``fade`` frames no new lock starts
and the offset fades to 0, so the arrival frame is the network's own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from model.inference.output.frame import Frame, StepParts
from model.inference.output.leg_chains import LegChains
from model.motion.kinematics import ChainKinematics
from model.motion.skeleton import Skeleton

Tensor = torch.Tensor


@dataclass(frozen=True)
class FootLockConfig:
    # Defaults chosen on the validation split with the default model (docs/experiments/2026-11-evaluation-history.md): tighter
    # contact and release than a first guess (3 / 5 / 10 cm, catch-up 0.5) hold the feet as well
    # and no longer cost style accuracy, since the leg is bent less far and lets go more gently.
    contact_cm: float = 1.5  # ankle height above the ground under which a slow foot locks
    lift_cm: float = 3.0  # ankle height above the ground at which a locked foot lets go
    plant_speed_cm_s: float = 60.0  # horizontal ankle speed under which a low foot counts as planted
    release_cm: float = 3.0  # drift of the generated ankle from the lock at which it lets go
    catch_up: float = 0.3  # share of the held offset removed each frame after a release
    rejoin_cm: float = 1.0  # a released foot locks again only once it is this close to the generated one
    fade: int = 5  # frames before arrival from which no lock starts and the offset fades out

    def __post_init__(self) -> None:
        if not 0 < self.contact_cm <= self.lift_cm:
            raise ValueError("foot lock needs 0 < contact_cm <= lift_cm")
        if not 0 < self.catch_up <= 1:
            raise ValueError("foot lock catch_up must be in (0, 1]")
        if self.plant_speed_cm_s <= 0 or self.release_cm <= 0 or self.rejoin_cm <= 0 or self.fade < 0:
            raise ValueError("foot lock speeds and distances must be positive, fade 0 or more")


@dataclass
class FootLockState:
    """Rows of characters: ``ground [N]`` (ankle ground height), ``locked [N, 2]``, ``anchor``,
    ``offset`` (shown minus generated ankle), ``previous`` (generated ankle) and ``carried`` (how far
    the engine's steering has moved the body since the foot locked) ``[N, 2, 3]``."""

    ground: Tensor
    locked: Tensor
    anchor: Tensor
    offset: Tensor
    previous: Tensor
    carried: Tensor

    FIELDS = ("ground", "locked", "anchor", "offset", "previous", "carried")
    # The engine keeps the fields as named rows of its batch's per-character memory, under these keys.
    MEMORY_KEYS = tuple(f"lock_{f}" for f in FIELDS)

    def memory(self) -> dict[str, Tensor]:
        """The fields under :attr:`MEMORY_KEYS`."""
        return {k: getattr(self, f) for k, f in zip(self.MEMORY_KEYS, self.FIELDS)}

    @classmethod
    def from_memory(cls, memory: dict[str, Tensor]) -> FootLockState:
        return cls(*(memory[k] for k in cls.MEMORY_KEYS))


class FootLock:
    """Batched foot locking for one skeleton (Y up, cm) at ``fps``: both legs in one pass, no per-row branches."""

    def __init__(self, skeleton: Skeleton, fps: float, config: FootLockConfig | None = None,
                 kinematics: ChainKinematics | None = None, legs: LegChains | None = None) -> None:
        """``kinematics``: the feet's chains (:func:`model.motion.kinematics.feet_kinematics`) to
        use, e.g. the one floor contact uses, so that the frame output computes them once for both;
        ``legs``: the skeleton's legs over them, where the caller has them."""
        self.config = config or FootLockConfig()
        self.fps = fps
        self.legs = LegChains(skeleton, kinematics) if legs is None else legs

    @property
    def kinematics(self) -> ChainKinematics:
        return self.legs.kinematics

    def ankles(self, rotations: Tensor, roots: Tensor) -> Tensor:
        """World ankle positions ``[N, 2, 3]`` of local ``rotations [N, J, 4]`` and ``roots [N, 3]``."""
        return self.legs.poses(rotations, roots)[0][:, -1]

    def start(self, rotations: Tensor, roots: Tensor) -> FootLockState:
        """State of one character from its context ``[T, J, 4]``, ``[T, 3]``."""
        ank = self.ankles(rotations, roots)  # [T, 2, 3]
        ground = ank[..., 1].min().view(1)
        last, before = ank[-1], ank[-2] if ank.shape[0] > 1 else ank[-1]
        speed = (last - before)[..., [0, 2]].norm(dim=-1) * self.fps
        locked = ((last[..., 1] - ground) < self.config.contact_cm) & (speed < self.config.plant_speed_cm_s)
        return FootLockState(ground, locked.view(1, 2), last.view(1, 2, 3).clone(), torch.zeros(1, 2, 3),
                             last.view(1, 2, 3).clone(), torch.zeros(1, 2, 3))

    def apply(self, rotations: Tensor, roots: Tensor, remaining: Tensor, state: FootLockState,
              skip_idle: bool = True, shift: Tensor | None = None,
              chains: tuple[Tensor, Tensor] | None = None, warp: Tensor | None = None) -> tuple[Tensor, FootLockState]:
        """Lock the feet of one frame of ``N`` characters; returns new local rotations and state.

        Args:
            rotations, roots: ``[N, J, 4]`` local rotations and ``[N, 3]`` roots (world).
            remaining: ``[N]`` frames left after this one (0 on the arrival frame).
            skip_idle: return early when no foot needs moving (eager use); False keeps the
                operations independent of the data, as a traced graph needs.
            shift: ``[N, 3]`` how far the engine's steering (:mod:`model.inference.output.steering`) moved
                the whole body this frame. A foot the network keeps still is then still in the
                network's motion, not in the world: planting and drift are judged without the
                shift, so the lock holds the foot while the body is carried over it.
            chains: world ``(positions [N, K, 3], rotations [N, K, 4])`` of :attr:`kinematics`' joints
                for these rotations and roots, where the caller has them (the frame output does).
            warp: ``[N, 2, 3]`` where the stride warp (the step before, in the output pipeline) moves each
                ankle: the lock treats the moved ankles as the generated ones, and one IK reaches both.
        """
        c = self.config
        pos, grot = self.legs.poses(rotations, roots, chains)
        ank = pos[:, -1] if warp is None else pos[:, -1] + warp  # [N, 2, 3]
        step = torch.zeros_like(ank) if shift is None else shift.unsqueeze(1).expand_as(ank)
        carried = state.carried + step
        height = ank[..., 1] - state.ground.unsqueeze(-1)
        speed = (ank - step - state.previous)[..., ::2].norm(dim=-1) * self.fps  # x, z
        open_time = (remaining >= c.fade).unsqueeze(-1)  # [N, 1]
        drift = (ank - carried - state.anchor)[..., ::2].norm(dim=-1)
        keep = state.locked & (height < c.lift_cm) & (drift < c.release_cm) & open_time
        rejoined = state.offset.norm(dim=-1) < c.rejoin_cm  # no re-lock mid catch-up: the foot would hop
        begin = ~state.locked & rejoined & (height < c.contact_cm) & (speed < c.plant_speed_cm_s) & open_time
        anchor = torch.where(begin.unsqueeze(-1), ank + state.offset, state.anchor)
        locked = keep | begin
        carried = torch.where(keep.unsqueeze(-1), carried, torch.zeros_like(carried))
        fade = (remaining.float() / max(c.fade, 1)).clamp(0.0, 1.0).view(-1, 1, 1)
        offset = torch.where(locked.unsqueeze(-1), anchor - ank, state.offset * (1.0 - c.catch_up) * fade)
        new_state = FootLockState(state.ground, locked, anchor, offset, ank, carried)
        total = offset if warp is None else offset + warp
        move = total.norm(dim=-1) > 1e-4  # [N, 2]
        if skip_idle and not bool(move.any()):
            return rotations, new_state
        return self.legs.bend(rotations, pos, grot, ank + offset, move), new_state


class FootLockStep:
    """The foot lock as a frame step (:mod:`model.inference.output.frame`), last of the steps that move feet but
    the foot plant: it reads the legs the steps before computed, reaches the ankles the stride warp moved, and judges
    planted feet against what the warp left of steering's shift."""

    MEMORY_KEYS: ClassVar[tuple[str, ...]] = FootLockState.MEMORY_KEYS
    COLUMNS: ClassVar[tuple[str, ...]] = ()

    def __init__(self, lock: FootLock) -> None:
        self.lock = lock

    @classmethod
    def build(cls, parts: StepParts) -> FootLockStep | None:
        return cls(FootLock(parts.skeleton, parts.fps, legs=parts.legs)) if parts.settings.foot_lock else None

    def start(self, rotations: Tensor, roots: Tensor) -> dict[str, Tensor]:
        return self.lock.start(rotations, roots).memory()

    def __call__(self, frame: Frame, memory: dict[str, Tensor], new: dict[str, Tensor]) -> None:
        frame.local, state = self.lock.apply(frame.local, frame.root, frame.remaining, FootLockState.from_memory(memory),
                                             skip_idle=frame.eager, shift=frame.world_shift(),
                                             chains=frame.chains_of(self.lock.kinematics), warp=frame.ankle_moves)
        new.update(state.memory())

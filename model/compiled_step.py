"""The sampler's per-frame step, its conversion to world space and the foot lock, traced to
TorchScript: the fastest path measured on this CPU.

At batch 1 a step is a few dozen small operations, so Python dispatch costs as much as the
arithmetic: tracing halves it (0.70 -> 0.36 ms per step on the 2-core development machine, with
the default model) and still helps at batch 64 (6.0 -> 5.1 ms). ONNX Runtime and torch.compile
were not needed to reach the target; eager remains available (``RSMT_EAGER=1`` or ``compiled=False``).

The traced graph takes and returns flat tensors; the dataclasses are rebuilt around it. It is
shape-generic in the batch and in the style-code length (verified against eager in the tests).
"""

from __future__ import annotations

import logging
import warnings

import torch

from model.features import CanonicalFrame
from model.foot_lock import FootLock, FootLockState
from model.kinematics import global_to_local_rotations
from model.representation import PoseState
from model.rotations import sixd_to_quat
from model.sampler import SamplerState, StyleContext, TransitionSampler
from model.skeleton import Skeleton

log = logging.getLogger(__name__)
Tensor = torch.Tensor


class _FlatStep(torch.nn.Module):
    def __init__(self, sampler: TransitionSampler) -> None:
        super().__init__()
        self.sampler = sampler

    def forward(self, h: Tensor, c: Tensor, rel: Tensor, vel: Tensor, rot: Tensor, root_xz: Tensor, phase: Tensor,
                target_vec: Tensor, target_pos: Tensor, target_rot: Tensor, target_emb: Tensor, tta: Tensor,
                noise: Tensor, g1: Tensor, b1: Tensor, k1: Tensor, v1: Tensor, g2: Tensor, b2: Tensor, k2: Tensor,
                v2: Tensor, mask: Tensor) -> tuple[Tensor, ...]:
        state = SamplerState(h, c, PoseState(rel, vel, rot, root_xz), phase, target_vec, target_pos, target_rot,
                             target_emb, tta, noise)
        style = StyleContext(g1, b1, k1, v1, g2, b2, k2, v2, mask)
        new, _ = self.sampler.step(state, style)
        return new.h, new.c, new.pose.rel, new.pose.vel, new.pose.rot, new.pose.root_xz, new.phase, new.tta


def _flat(state: SamplerState, style: StyleContext) -> tuple[Tensor, ...]:
    p = state.pose
    return (state.h, state.c, p.rel, p.vel, p.rot, p.root_xz, state.phase, state.target_vec, state.target_pos,
            state.target_rot, state.target_emb, state.tta, state.noise, style.gamma1, style.beta1, style.keys1,
            style.values1, style.gamma2, style.beta2, style.keys2, style.values2, style.mask)


class CompiledStep:
    """``step(state, style) -> state`` through a traced graph, built on first use."""

    def __init__(self, sampler: TransitionSampler) -> None:
        self.sampler = sampler
        self._graph: torch.jit.ScriptModule | None = None
        self.failed = False

    def __call__(self, state: SamplerState, style: StyleContext) -> SamplerState:
        if self._graph is None and not self.failed:
            self._build(state, style)
        if self._graph is None:
            return self.sampler.step(state, style)[0]
        h, c, rel, vel, rot, root_xz, phase, tta = self._graph(*_flat(state, style))
        return SamplerState(h, c, PoseState(rel, vel, rot, root_xz), phase, state.target_vec, state.target_pos,
                            state.target_rot, state.target_emb, tta, state.noise)

    def _build(self, state: SamplerState, style: StyleContext) -> None:
        self._graph = _trace(_FlatStep(self.sampler), _flat(state, style))
        self.failed = self._graph is None


def world_pose(pose: PoseState, yaw: Tensor, origin: Tensor, parents: list[int], root: int) -> tuple[Tensor, Tensor]:
    """A generated pose (canonical frame) in world space: local quaternions ``[N, J, 4]`` and root
    positions ``[N, 3]``, for each row's :class:`CanonicalFrame` ``yaw [N]`` and ``origin [N, 3]``."""
    frame = CanonicalFrame(yaw, origin)
    grot = frame.rotations_from(sixd_to_quat(pose.rot))
    root_pos = frame.positions_from(pose.positions()[:, root])
    return global_to_local_rotations(grot, parents), root_pos


class _WorldPose(torch.nn.Module):
    def __init__(self, parents: list[int], root: int) -> None:
        super().__init__()
        self.parents, self.root = parents, root

    def forward(self, rel: Tensor, vel: Tensor, rot: Tensor, root_xz: Tensor, yaw: Tensor,
                origin: Tensor) -> tuple[Tensor, Tensor]:
        return world_pose(PoseState(rel, vel, rot, root_xz), yaw, origin, self.parents, self.root)


class CompiledWorldPose:
    """:func:`world_pose` for one skeleton; with ``traced`` through a graph built on first use
    (eager if tracing fails).

    At batch 1 the conversion is about 40 small operations: 0.23 ms eager on the development
    machine, a quarter of a whole frame, which tracing cuts like the step's own dispatch cost.
    """

    def __init__(self, skeleton: Skeleton, traced: bool = True) -> None:
        self.parents, self.root = list(skeleton.parents), skeleton.roles.root
        self._graph: torch.jit.ScriptModule | None = None
        self.failed = not traced

    def __call__(self, pose: PoseState, yaw: Tensor, origin: Tensor) -> tuple[Tensor, Tensor]:
        if self._graph is None and not self.failed:
            self._graph = _trace(_WorldPose(self.parents, self.root), (pose.rel, pose.vel, pose.rot, pose.root_xz, yaw, origin))
            self.failed = self._graph is None
        if self._graph is None:
            return world_pose(pose, yaw, origin, self.parents, self.root)
        local, root = self._graph(pose.rel, pose.vel, pose.rot, pose.root_xz, yaw, origin)
        return local, root


class _FlatFootLock(torch.nn.Module):
    def __init__(self, lock: FootLock) -> None:
        super().__init__()
        self.lock = lock

    def forward(self, rotations: Tensor, roots: Tensor, remaining: Tensor, ground: Tensor, locked: Tensor,
                anchor: Tensor, offset: Tensor, previous: Tensor) -> tuple[Tensor, ...]:
        out, st = self.lock.apply(rotations, roots, remaining, FootLockState(ground, locked, anchor, offset, previous),
                                  skip_idle=False)
        return out, st.locked, st.anchor, st.offset, st.previous


class CompiledFootLock:
    """:meth:`FootLock.apply` through a graph traced on first use (eager if tracing fails or ``traced`` is False).

    Eager, the lock is about 300 small operations (leg kinematics, two-bone IK, local rotations):
    0.8-1.1 ms at batch 1 on the development machine, as much as the network's step. Traced, it
    always runs the IK (no early return when no foot is held), which costs less than the dispatch it saves.
    """

    def __init__(self, lock: FootLock, traced: bool = True) -> None:
        self.lock = lock
        self._graph: torch.jit.ScriptModule | None = None
        self.failed = not traced

    def start(self, rotations: Tensor, roots: Tensor) -> FootLockState:
        return self.lock.start(rotations, roots)

    def apply(self, rotations: Tensor, roots: Tensor, remaining: Tensor, state: FootLockState) -> tuple[Tensor, FootLockState]:
        args = (rotations, roots, remaining, state.ground, state.locked, state.anchor, state.offset, state.previous)
        if self._graph is None and not self.failed:
            self._graph = _trace(_FlatFootLock(self.lock), args)
            self.failed = self._graph is None
        if self._graph is None:
            return self.lock.apply(rotations, roots, remaining, state)
        out, locked, anchor, offset, previous = self._graph(*args)
        return out, FootLockState(state.ground, locked, anchor, offset, previous)


def _trace(module: torch.nn.Module, args: tuple[Tensor, ...]) -> torch.jit.ScriptModule | None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            # torch 2.13 marks jit.trace deprecated in favour of torch.compile/export; it still
            # works, and compile needs a long C++ build at start-up that a 2-core server pays badly.
            warnings.simplefilter("ignore", DeprecationWarning)
            return torch.jit.freeze(torch.jit.trace(module.eval(), args, check_trace=False))
    except Exception as exc:  # noqa: BLE001 - any tracing failure falls back to eager
        log.warning("tracing %s failed (%s); using eager", type(module).__name__, exc)
        return None

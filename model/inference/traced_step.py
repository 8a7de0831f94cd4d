"""The sampler's per-frame step (with root steering), and the output pipeline's frame steps
(:mod:`model.inference.output.pipeline`), traced to TorchScript: the fastest path measured on this CPU.

At batch 1 a step is a few dozen small operations, so Python dispatch costs as much as the
arithmetic: tracing halves it (0.70 -> 0.36 ms per step on the 2-core development machine, with
the default model) and still helps at batch 64 (6.0 -> 5.1 ms). ONNX Runtime and torch.compile
were not needed to reach the target; eager remains available (``compiled=False``; the service's ``RSMT_EAGER=1``).

The traced graph takes and returns flat tensors; the dataclasses are rebuilt around it. It is
shape-generic in the batch and in the style-code length (verified against eager in the tests).
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Callable
from typing import Any

import torch

from model.inference.graph_constants import dimensioned_constants
from model.inference.output.pipeline import FrameSteps
from model.inference.output.steering import SteeringConfig, steer
from model.motion.features import FacingChains
from model.nets.pose_state import PoseState
from model.nets.transition_net import NetState, TransitionNet

log = logging.getLogger(__name__)
Tensor = torch.Tensor


def step_and_steer(net: TransitionNet, state: NetState, style: Any, root: int,
                   steering: SteeringConfig, facing: FacingChains | None = None,
                   late: Tensor | None = None) -> tuple[NetState, Tensor | None]:
    """One frame of the network, then root steering where it is on (:mod:`model.inference.output.steering`;
    ``facing``: the skeleton's, for steering the facing; ``late [N]``: the rows retargeted mid-stream):
    the new state and the ground shift steering gave each row (None when off)."""
    new, _ = net.step(state, style)
    if not steering.on:
        return new, None
    return steer(new, root, steering, facing, late)


class _FlatStep(torch.nn.Module):
    """:func:`step_and_steer` on flat tensors: the state's and the style's (:meth:`TensorRecord.flat`), then
    ``late`` where given; it returns the state's carried tensors (:meth:`TensorRecord.carried`), then the shift
    where steering is on."""

    def __init__(self, net: TransitionNet, root: int, steering: SteeringConfig,
                 facing: FacingChains | None) -> None:
        super().__init__()
        self.net, self.root, self.steering, self.facing = net, root, steering, facing
        self._state_size = len(net.state_type.flat_names())
        self._style_size = len(net.style_type.flat_names())

    def forward(self, *args: Tensor) -> tuple[Tensor, ...]:
        n, m = self._state_size, self._style_size
        state = self.net.state_type.from_flat(args[:n])
        style = self.net.style_type.from_flat(args[n : n + m])
        late = args[n + m] if len(args) > n + m else None
        new, shift = step_and_steer(self.net, state, style, self.root, self.steering, self.facing, late)
        out = new.carried()
        return out if shift is None else (*out, shift)


def _flat(state: NetState, style: Any) -> tuple[Tensor, ...]:
    return (*state.flat(), *style.flat())


class _TracedOnFirstUse:
    """Graphs traced on first use, one per key, unless ``traced`` is False (eager by choice) or a
    trace fails (eager from then on: :attr:`trace_failed`)."""

    def __init__(self, traced: bool) -> None:
        self.traced = traced
        self.trace_failed = False
        self._graphs: dict[str, torch.jit.ScriptModule] = {}

    @property
    def eager(self) -> bool:
        """Whether calls run eagerly: by choice, or because tracing failed."""
        return not self.traced or self.trace_failed

    @property
    def _graph(self) -> torch.jit.ScriptModule | None:
        """The main graph, once traced."""
        return self._graphs.get("")

    def _graph_for(self, make: Callable[[], torch.nn.Module], args: tuple[Tensor, ...],
                   key: str = "") -> torch.jit.ScriptModule | None:
        """The traced graph ``key`` (the first time, ``make()`` traced on ``args``), or None when eager."""
        if key not in self._graphs and not self.eager:
            graph = _trace(make(), args)
            if graph is None:
                self.trace_failed = True
            else:
                self._graphs[key] = graph
        return None if self.eager else self._graphs.get(key)


class CompiledStep(_TracedOnFirstUse):
    """``step(state, style, late) -> (state, shift)``: :func:`step_and_steer` through a traced graph, built on
    first use (eager if tracing fails or ``traced`` is False). Steering is inside the graph: eager,
    its few dozen small operations cost about a quarter of the traced network step at batch 1.
    ``facing`` (the skeleton's :class:`FacingChains`) is needed where the steering turns the facing;
    ``late [N]`` (bool) flags the rows retargeted mid-stream, which matters only where the steering
    has a retarget window (another graph: batches without such rows keep the usual one)."""

    def __init__(self, net: TransitionNet, root: int, steering: SteeringConfig, traced: bool = True,
                 facing: FacingChains | None = None) -> None:
        super().__init__(traced)
        if steering.turns and facing is None:
            raise ValueError("steering the facing needs the skeleton's facing chains")
        self.net, self.root, self.steering, self.facing = net, root, steering, facing
        # Before the facing and height windows open, their parts move nothing: a second graph leaves them out.
        # A batch with no retargeted row steers as if the retarget window were off (its own graph).
        self._usual = dataclasses.replace(steering, retarget_turn_window=0)
        self._finish_from = max(steering.turn_window, steering.height_window)
        self._late_from = max(self._finish_from, steering.retarget_turn_window)
        self._cruise = (dataclasses.replace(steering, turn_window=0, height_window=0, retarget_turn_window=0)
                        if self._late_from else None)

    def __call__(self, state: NetState, style: Any,
                 late: Tensor | None = None) -> tuple[NetState, Tensor | None]:
        has_late = late is not None and self.steering.retarget_turn_window > 0 and bool(late.any())
        steering, key = (self.steering, "late") if has_late else (self._usual, "")
        finish_from = self._late_from if has_late else self._finish_from
        if self._cruise is not None and int(state.tta.min()) > finish_from:
            steering, key = self._cruise, "cruise"
        args = _flat(state, style)
        if key == "late":
            args = (*args, late)  # type: ignore[arg-type]
        else:
            late = None
        graph = self._graph_for(lambda: _FlatStep(self.net, self.root, steering, self.facing), args, key)
        if graph is None:
            return step_and_steer(self.net, state, style, self.root, steering, self.facing, late)
        out = graph(*args)
        carried = len(state.carried_names())
        return state.with_carried(out[:carried]), (out[carried] if len(out) > carried else None)


class _FlatFrameOutput(torch.nn.Module):
    def __init__(self, fn: FrameSteps) -> None:
        super().__init__()
        self.fn = fn

    def forward(self, rel: Tensor, vel: Tensor, rot: Tensor, root_xz: Tensor, yaw: Tensor, origin: Tensor,
                remaining: Tensor, shift: Tensor, *memory: Tensor) -> tuple[Tensor, ...]:
        local, root, new = self.fn(PoseState(rel, vel, rot, root_xz), yaw, origin, remaining,
                                   dict(zip(self.fn.keys, memory)), eager=False, shift=shift)
        return (local, root, *(new[k] for k in self.fn.keys))


class CompiledFrameOutput(_TracedOnFirstUse):
    """The output pipeline's frame steps (:class:`model.inference.output.pipeline.FrameSteps`) through one graph
    traced on first use (eager if tracing fails or
    ``traced`` is False).

    At batch 1 these steps are a few hundred small operations, bound by dispatch: eager they cost as
    much as the network's step (0.23-0.30 ms without the lock, about 1 ms with it on the development
    machine). One graph also pays the call overhead once; floor contact and the lock share the legs'
    forward kinematics, and indexes are kept tensors (a list index costs ~10 us a call traced).
    Traced, the foot lock always runs its IK (no early return when no foot is held), which costs less
    than the dispatch it saves.
    """

    def __init__(self, fn: FrameSteps, traced: bool = True) -> None:
        super().__init__(traced)
        self.fn = fn

    def __call__(self, pose: PoseState, yaw: Tensor, origin: Tensor, remaining: Tensor,
                 memory: dict[str, Tensor], shift: Tensor | None = None) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        if shift is None:
            shift = torch.zeros(pose.root_xz.shape)
        args = (pose.rel, pose.vel, pose.rot, pose.root_xz, yaw, origin, remaining, shift,
                *(memory[k] for k in self.fn.keys))
        graph = self._graph_for(lambda: _FlatFrameOutput(self.fn), args)
        if graph is None:
            return self.fn(pose, yaw, origin, remaining, memory, shift=shift)
        local, root, *rest = graph(*args)
        return local, root, dict(zip(self.fn.keys, rest))


def _trace(module: torch.nn.Module, args: tuple[Tensor, ...]) -> torch.jit.ScriptModule | None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", torch.jit.TracerWarning)
            # torch 2.13 marks jit.trace deprecated in favour of torch.compile/export; it still
            # works, and compile needs a long C++ build at start-up that a 2-core server pays badly.
            warnings.simplefilter("ignore", DeprecationWarning)
            traced = torch.jit.trace(module.eval(), args, check_trace=False)
            dimensioned_constants(traced.graph)  # while the traced graph still knows every value's dimensions
            return torch.jit.freeze(traced)
    except Exception as exc:  # noqa: BLE001 - any tracing failure falls back to eager
        log.warning("tracing %s failed (%s); using eager", type(module).__name__, exc)
        return None

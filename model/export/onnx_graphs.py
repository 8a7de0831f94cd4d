"""A served engine's networks as ONNX graphs: the style encoder, the warm-up, the per-frame step and the output steps.

Each graph is one of the engine's own computations with its tensors laid flat (names below), traced by
the TorchScript-based exporter at opset 15 (:mod:`model.export.onnx_symbolics`) with the batch, and the
style code's length, left dynamic:

* ``prepare``: one character's context and target poses to ``begin``'s inputs, the canonical frame and the
  output steps' first memory (:mod:`model.export.onnx_prepare`; a batch of one);
* ``style``: a style clip's poses (local rotations ``[B, T, J, 4]``, roots ``[B, T, 3]``, on the model's rig at
  its fps) to the style context (for RSMT: FiLM and attention tensors);
* ``begin``: the context and target states to the network's state before the first frame;
* ``step``: one frame of the network and its steering (the recurrent state in and out);

The graphs' tensor names come from the network's records (:class:`Layout`), so any network behind the seam
(:mod:`model.nets.transition_net`) exports; for the RSMT sampler they are the names ``docs/onnx.md`` lists.
* ``output``: the output steps (world space, smoothing, floor contact, stride warp, foot lock), their
  per-character memory in and out.

The engine's torch path runs the same modules (:mod:`model.inference.traced_step`), so the graphs and
the engine compute the same frames.
"""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from typing import Any

import torch

from model.data.synthetic import synthetic_walk
from model.export.onnx_symbolics import OPSET, exporting
from model.inference.character import WeightSet
from model.inference.character_batch import CharacterBatch
from model.inference.engine import Engine
from model.inference.traced_step import _flat, _FlatFrameOutput, _FlatStep
from model.motion.features import local_frame_features
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize
from model.motion.skeleton import Skeleton
from model.nets.pose_state import PoseState
from model.nets.transition_net import NetState, TransitionNet

Tensor = torch.Tensor

POSE_INPUTS = ("rel", "vel", "rot", "root_xz")
OUTPUT_INPUTS = (*POSE_INPUTS, "yaw", "origin", "remaining", "shift")


@dataclass(frozen=True)
class Layout:
    """The names of a network's graphs' tensors, from its records (:mod:`model.nets.tensor_record`): its style
    context's fields, its state's, the state's carried fields (a step's outputs before ``shift``) and the time axis
    of each style field that has one."""

    style: tuple[str, ...]
    state: tuple[str, ...]
    carried: tuple[str, ...]
    style_steps: dict[str, int]

    @classmethod
    def of(cls, net: TransitionNet) -> Layout:
        return cls(net.style_type.flat_names(), net.state_type.flat_names(), net.state_type.carried_names(),
                   dict(net.style_type.TIME_AXES))

    @property
    def begin_inputs(self) -> tuple[str, ...]:
        return (*(f"context_{n}" for n in POSE_INPUTS), *(f"target_{n}" for n in POSE_INPUTS), "frames", "noise",
                "velocity_known", *self.style)

    @property
    def step_inputs(self) -> tuple[str, ...]:
        return (*self.state, *self.style, "late")

    @property
    def step_outputs(self) -> tuple[str, ...]:
        return (*(f"{n}_out" for n in self.carried), "shift")

    def style_axes(self) -> dict[str, dict[int, str]]:
        """Dynamic axes of the style tensors: the batch, and the code's time steps where they have one."""
        steps = self.style_steps
        return {n: {0: "batch", **({steps[n]: "style_steps"} if n in steps else {})} for n in self.style}


@dataclass(frozen=True)
class Graph:
    """One exported graph: its ONNX bytes and the names of its inputs and outputs, in order."""

    name: str
    model: bytes
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]


def _export(name: str, module: torch.nn.Module, args: tuple[Tensor, ...], inputs: tuple[str, ...],
            outputs: tuple[str, ...], axes: dict[str, dict[int, str]]) -> Graph:
    buffer = io.BytesIO()
    with exporting(), warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer warnings on shapes read as numbers (fixed by the skeleton)
        # The TorchScript exporter writes to a file object too (its annotation says paths only).
        torch.onnx.export(module.eval(), args, buffer, input_names=list(inputs),  # type: ignore[arg-type]
                          output_names=list(outputs), opset_version=OPSET, dynamo=False, dynamic_axes=axes)
    import onnx

    graph = onnx.load_from_string(buffer.getvalue()).graph  # the exporter drops inputs a graph never reads
    return Graph(name, buffer.getvalue(), tuple(i.name for i in graph.input), tuple(o.name for o in graph.output))


class _Step(_FlatStep):
    """The step with the ground shift always returned (zeros where steering is off), so every bundle's graph has one layout."""

    def forward(self, *args: Tensor) -> tuple[Tensor, ...]:
        out = super().forward(*args)
        carried = self.net.state_type.carried_names()
        return out if len(out) > len(carried) else (*out, torch.zeros_like(out[carried.index("root_xz")]))


class _Style(torch.nn.Module):
    offsets: Tensor

    def __init__(self, net: TransitionNet, skeleton: Skeleton) -> None:
        super().__init__()
        self.net, self.skeleton = net, skeleton
        self.register_buffer("offsets", skeleton.offsets_tensor())

    def forward(self, rotations: Tensor, roots: Tensor) -> tuple[Tensor, ...]:
        pos, rot = forward_kinematics(quat_normalize(rotations), roots, self.offsets, self.skeleton.parents)
        features = local_frame_features(pos, rot, self.skeleton)
        return tuple(self.net.style_context(self.net.encode_style(features)).flat())


class _Begin(torch.nn.Module):
    def __init__(self, net: TransitionNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, crel: Tensor, cvel: Tensor, crot: Tensor, croot: Tensor, trel: Tensor, tvel: Tensor,
                trot: Tensor, troot: Tensor, frames: Tensor, noise: Tensor, known: Tensor,
                *style: Tensor) -> tuple[Tensor, ...]:
        state = self.net.begin(PoseState(crel, cvel, crot, croot), PoseState(trel, tvel, trot, troot), frames,
                               noise, self.net.style_type.from_flat(style), velocity_known=known)
        return tuple(state.flat())


@dataclass
class Example:
    """A batch of two characters prepared by the engine (one retargeted), traced through to give every
    graph its example inputs."""

    style_poses: tuple[Tensor, Tensor]
    begin: tuple[Tensor, ...]
    state: NetState
    style: Any
    late: Tensor
    output: tuple[Tensor, ...]

    @classmethod
    def of(cls, engine: Engine, weights: WeightSet) -> Example:
        c = engine.config
        walk = synthetic_walk(frames=160, turn_deg_s=15.0)  # a procedural walk: a request any rig's engine accepts
        style_clip = engine.conform(walk.window(20, 20 + min(120, c.style_frames_max)))
        style_poses = (style_clip.rotations.unsqueeze(0), style_clip.root_positions.unsqueeze(0))
        style, cached = engine.encode_style(style_clip, weights=weights.name)
        if not cached:  # an example, not a style anyone registered
            engine.styles.delete(style.style_id)
        frames = c.max_transition
        context, target = walk.window(0, c.context), walk.window(c.context + frames - 2, c.context + frames)
        chars = [engine.prepare(context, target, frames, style, seed=i) for i in range(2)]
        starts = [c.parked.prepared for c in chars if c.parked is not None and c.parked.prepared is not None]
        assert len(starts) == len(chars)
        ctx = PoseState.cat([p.context for p in starts])
        tgt = PoseState.cat([p.target for p in starts])
        begin = (ctx.rel, ctx.vel, ctx.rot, ctx.root_xz, tgt.rel, tgt.vel, tgt.rot, tgt.root_xz,
                 torch.tensor([p.frames for p in starts]), torch.cat([p.noise for p in starts]),
                 torch.tensor([p.velocity_known for p in starts]))
        batch = CharacterBatch(engine)
        for ch in chars:
            batch.add(ch)
        state, ctx_style, yaw, origin, memory = batch.stacked()
        late = torch.tensor([False, True])
        new, shift = weights.step_fn(state, ctx_style, late)
        shift = torch.zeros(2, 2) if shift is None else shift
        p = new.pose
        output = (p.rel, p.vel, p.rot, p.root_xz, yaw, origin, torch.tensor([30, 3]), shift,
                  *(memory[k] for k in engine.output_fn.fn.keys))
        return cls(style_poses, begin, state, ctx_style, late, output)


def style_graph(engine: Engine, weights: WeightSet, example: Example) -> Graph:
    layout = Layout.of(weights.net)
    axes = {"rotations": {0: "batch", 1: "frames"}, "roots": {0: "batch", 1: "frames"}, **layout.style_axes()}
    return _export("style", _Style(weights.net, engine.skeleton), example.style_poses, ("rotations", "roots"),
                   layout.style, axes)


def begin_graph(weights: WeightSet, example: Example) -> Graph:
    layout = Layout.of(weights.net)
    outputs = tuple(f"{n}_out" for n in layout.state)
    axes = {n: {0: "batch"} for n in (*layout.begin_inputs, *outputs) if n not in layout.style}
    args = (*example.begin, *example.style.flat())
    return _export("begin", _Begin(weights.net), args, layout.begin_inputs, outputs, axes | layout.style_axes())


def step_graph(engine: Engine, weights: WeightSet, example: Example) -> Graph:
    """The network's step with the engine's whole steering (the retarget window for rows flagged ``late``)."""
    layout = Layout.of(weights.net)
    module = _Step(weights.net, engine.skeleton.roles.root, engine.output.steering, engine.facing)
    axes = {n: {0: "batch"} for n in (*layout.state, "late", *layout.step_outputs)} | layout.style_axes()
    args = (*_flat(example.state, example.style), example.late)
    return _export("step", module, args, layout.step_inputs, layout.step_outputs, axes)


def output_graph(engine: Engine, example: Example) -> Graph:
    keys = tuple(engine.output_fn.fn.keys)
    inputs = (*OUTPUT_INPUTS, *keys)
    outputs = ("rotations", "root_position", *(f"{k}_out" for k in keys))
    axes = {n: {0: "batch"} for n in (*inputs, *outputs)}
    return _export("output", _FlatFrameOutput(engine.output_fn.fn), example.output, inputs, outputs, axes)


def prepare_graph(engine: Engine) -> Graph:
    from model.export.onnx_prepare import PREPARE_INPUTS, PREPARE_STATES, Prepare, prepare_example

    keys = tuple(engine.output_fn.fn.keys)
    axes = {"context_rotations": {0: "frames"}, "context_roots": {0: "frames"}}
    return _export("prepare", Prepare(engine), prepare_example(engine), PREPARE_INPUTS, (*PREPARE_STATES, *keys), axes)

"""The onnxruntime backend: an engine whose per-frame step and output steps run as ONNX graphs in onnxruntime.

:func:`use_onnxruntime` exports a served engine's graphs in memory (:mod:`model.export.onnx_graphs`) and
puts onnxruntime sessions where the engine keeps its traced step and output graphs (each weight set's
``step_fn`` and the engine's ``output_fn``). Everything else (preparing requests, the warm-up on the
context, style encoding, exact arrival, batching) stays the engine's: the two backends share one code
path around the graphs, and give the same frames (tests/inference/test_onnx_parity.py).

The graphs hold the float32 network: a bundle's ``int8_lstm`` setting applies to the torch backend only.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import torch

from model.inference.character import WeightSet
from model.inference.engine import Engine
from model.inference.traced_step import CompiledFrameOutput, CompiledStep, _flat
from model.nets.pose_state import PoseState
from model.nets.transition_net import NetState

Tensor = torch.Tensor
log = logging.getLogger(__name__)


def session(model: bytes, threads: int) -> Any:
    """An onnxruntime CPU session of ``model`` on ``threads`` intra-op threads, every graph optimisation on."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = max(1, threads)
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.log_severity_level = 3  # warnings about unused initialisers are the exporter's, not the caller's
    return ort.InferenceSession(model, options, providers=["CPUExecutionProvider"])


def _numpy(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class OnnxStep(CompiledStep):
    """A weight set's per-frame step (:class:`CompiledStep`'s call) run by one onnxruntime session."""

    def __init__(self, engine: Engine, weights: WeightSet, model: bytes, threads: int) -> None:
        super().__init__(weights.net, engine.skeleton.roles.root, engine.output.steering, traced=False,
                         facing=engine.facing)
        self.session = session(model, threads)
        self._inputs = [i.name for i in self.session.get_inputs()]
        self._names = (*weights.net.state_type.flat_names(), *weights.net.style_type.flat_names())

    def __call__(self, state: NetState, style: Any,
                 late: Tensor | None = None) -> tuple[NetState, Tensor | None]:
        if late is None:
            late = torch.zeros(state.tta.shape, dtype=torch.bool)
        values = dict(zip(self._names, _flat(state, style)))
        values["late"] = late
        *carried, shift = (torch.from_numpy(a) for a in self.session.run(None, {n: _numpy(values[n]) for n in self._inputs}))
        return state.with_carried(carried), (shift if self.steering.on else None)


class OnnxFrameOutput(CompiledFrameOutput):
    """The engine's output steps (:class:`CompiledFrameOutput`'s call) run by one onnxruntime session."""

    def __init__(self, output: CompiledFrameOutput, model: bytes, threads: int) -> None:
        super().__init__(output.fn, traced=False)
        self.session = session(model, threads)
        self._inputs = [i.name for i in self.session.get_inputs()]

    def __call__(self, pose: PoseState, yaw: Tensor, origin: Tensor, remaining: Tensor,
                 memory: dict[str, Tensor], shift: Tensor | None = None) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        if shift is None:
            shift = torch.zeros(pose.root_xz.shape)
        values = {"rel": pose.rel, "vel": pose.vel, "rot": pose.rot, "root_xz": pose.root_xz, "yaw": yaw,
                  "origin": origin, "remaining": remaining, "shift": shift, **memory}
        out = self.session.run(None, {n: _numpy(values[n]) for n in self._inputs})
        local, root, *rest = (torch.from_numpy(a) for a in out)
        return local, root, dict(zip(self.fn.keys, rest))


def use_onnxruntime(engine: Engine, threads: int | None = None) -> Engine:
    """``engine`` with every weight set's step and its output steps run by onnxruntime (``threads``:
    intra-op threads; default torch's current setting). Returns the same engine."""
    try:
        import onnx  # noqa: F401  (the exporter needs it)
        import onnxruntime  # noqa: F401
    except ImportError as exc:
        raise ValueError(f"the onnxruntime backend needs onnx and onnxruntime: pip install 'rsmt[onnx]' ({exc})") from exc
    from model.export.onnx_graphs import Example, output_graph, step_graph

    threads = threads or torch.get_num_threads()
    for name, ws in engine.weight_sets.items():
        example = Example.of(engine, ws)
        ws.step_fn = OnnxStep(engine, ws, step_graph(engine, ws, example).model, threads)
        if not name:
            engine.output_fn = OnnxFrameOutput(engine.output_fn, output_graph(engine, example).model, threads)
    engine.step_fn = engine.weight_sets[""].step_fn
    # The sessions hold the float32 network: the engine says so where it describes itself (bench labels).
    engine.inference = engine.inference.with_overrides(int8_lstm=False)
    return engine

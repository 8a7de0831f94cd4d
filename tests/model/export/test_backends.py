"""Choosing the backend of an engine: torch keeps its traced graphs, onnxruntime swaps in sessions, others are refused."""

from __future__ import annotations

import pytest

from model.export.backends import backend_of, with_backend
from model.export.onnx_backend import OnnxFrameOutput, OnnxStep
from model.inference.engine import Engine
from tests.model.tiny_bundles import tiny_bundle


def test_each_backend_runs_the_engine_it_is_given_and_an_unknown_one_is_refused(walk):
    bundle = tiny_bundle(3)
    torch_engine = with_backend(Engine(bundle), "torch")
    assert backend_of(torch_engine) == "torch" and not isinstance(torch_engine.output_fn, OnnxFrameOutput)
    onnx_engine = with_backend(Engine(bundle), "onnxruntime")
    assert backend_of(onnx_engine) == "onnxruntime"
    assert all(isinstance(ws.step_fn, OnnxStep) for ws in onnx_engine.weight_sets.values())
    assert len(onnx_engine.styles) == 0  # exporting leaves no style in the cache
    frames = []
    for engine in (torch_engine, onnx_engine):
        style, _ = engine.encode_style(walk.window(30, 150))
        frames.append(engine.generate([engine.prepare(walk.window(0, 10), walk.window(40, 42), 20, style,
                                                      deterministic=True)])[0])
    assert (frames[0][1] - frames[1][1]).abs().max() < 1e-3  # the same root path (cm)
    with pytest.raises(ValueError, match="torch, onnxruntime"):
        with_backend(Engine(bundle), "tensorrt")

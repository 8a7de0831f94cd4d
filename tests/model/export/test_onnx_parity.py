"""Parity: onnxruntime runs the default bundle's transitions (starts and mid-stream retargets, every output step on)
to within 1e-3 cm of the torch engine on every joint, both in float32."""

from __future__ import annotations

import pytest
import torch

from model.export.onnx_backend import OnnxFrameOutput, OnnxStep, use_onnxruntime
from model.export.onnx_parity import FRAMES, parity_cases, run_cases
from model.inference.bundle import DEFAULT_BUNDLE, Bundle
from model.inference.engine import Engine
from model.inference.overrides import Overrides

pytestmark = pytest.mark.slow  # 50 transitions through onnxruntime and the torch engine


def test_onnxruntime_matches_the_torch_engine_within_a_hundredth_of_a_millimetre() -> None:
    bundle = Bundle.load(DEFAULT_BUNDLE)
    torch_engine = Engine(bundle, overrides=Overrides(int8_lstm=False))  # the graphs hold the float32 network
    onnx_engine = use_onnxruntime(Engine(bundle, overrides=Overrides(int8_lstm=False)))
    assert isinstance(onnx_engine.step_fn, OnnxStep) and isinstance(onnx_engine.output_fn, OnnxFrameOutput)
    out = onnx_engine.output
    assert out.foot_lock and out.floor and out.smooths and out.stride_warp > 0 and out.steering.on  # every step on
    cases = parity_cases(50)
    assert sum(c.retarget is not None for c in cases) == 10
    expected, got = run_cases(torch_engine, cases), run_cases(onnx_engine, cases)
    assert got.shape == (50, FRAMES, bundle.skeleton.num_joints, 3)
    moved = (expected[:, -1, 0] - expected[:, 0, 0]).norm(dim=-1)
    assert bool((moved > 30.0).all()), "every case walks somewhere"
    error = (expected - got).norm(dim=-1)
    assert float(error.max()) < 1e-3, f"largest joint distance {float(error.max()):.2e} cm"
    # Not the same computation run twice: a retarget moves its case's frames by far more than the tolerance.
    retargeted = [i for i, c in enumerate(cases) if c.retarget is not None]
    plain = run_cases(torch_engine, [c.__class__(c.context, c.target, c.style, c.seed, None) for c in
                                     (cases[i] for i in retargeted)])
    assert float((plain - expected[retargeted]).norm(dim=-1).amax(dim=(1, 2)).min()) > 1.0
    assert torch.isfinite(got).all()

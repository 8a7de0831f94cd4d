"""Which runtime runs an engine's per-frame graphs: ``torch`` (traced TorchScript graphs, the int8 LSTM where the
bundle asks for it) or ``onnxruntime`` (the same graphs exported to ONNX, float32; :mod:`model.export.onnx_backend`).

Both give the same frames within float32 rounding (tests/model/export/test_onnx_parity.py); the int8 LSTM is the
torch backend's only, and moves frames by more than that. ``rsmt bench --backend both`` measures the two side by
side; :data:`DEFAULT_BACKEND` is the one that measured faster on the development machine (docs/benchmarks.md).
"""

from __future__ import annotations

from model.inference.engine import Engine

BACKENDS = ("torch", "onnxruntime")
DEFAULT_BACKEND = "torch"


def with_backend(engine: Engine, backend: str = DEFAULT_BACKEND) -> Engine:
    """``engine`` running on ``backend`` (one of :data:`BACKENDS`); the same engine object."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "onnxruntime":
        from model.export.onnx_backend import use_onnxruntime

        return use_onnxruntime(engine)
    return engine


def backend_of(engine: Engine) -> str:
    """The backend ``engine`` runs on."""
    from model.export.onnx_backend import OnnxStep

    return "onnxruntime" if isinstance(engine.step_fn, OnnxStep) else "torch"

"""What the TorchScript-based ONNX exporter needs that torch 2.13 does not give it at opset 15.

The sampler normalises with ``layer_norm(x, x.shape[-1:])``. Traced for ONNX, that shape is a value
of the graph, which the stock symbolic refuses (it wants constants), and opset 15 has no
LayerNormalization node. :func:`layer_norm_over_last_axes` writes the normalisation out over the
trailing axes with ReduceMean, which every ONNX runtime from opset 7 runs.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import torch
from torch.onnx._internal.torchscript_exporter import symbolic_helper

OPSET = 15


def layer_norm_over_last_axes(g: Any, x: Any, shape: Any, weight: Any, bias: Any, eps: Any, cudnn: Any) -> Any:
    """``aten::layer_norm`` over as many trailing axes as ``shape`` has entries, whatever their values."""
    axes = list(range(-len(symbolic_helper._unpack_list(shape)), 0))
    epsilon = g.op("Constant", value_t=torch.tensor(symbolic_helper._parse_arg(eps, "f"), dtype=torch.float32))
    centred = g.op("Sub", x, g.op("ReduceMean", x, axes_i=axes))
    variance = g.op("ReduceMean", g.op("Mul", centred, centred), axes_i=axes)
    y = g.op("Div", centred, g.op("Sqrt", g.op("Add", variance, epsilon)))
    if not symbolic_helper._is_none(weight):
        y = g.op("Mul", y, weight)
    if not symbolic_helper._is_none(bias):
        y = g.op("Add", y, bias)
    return y


@contextmanager
def exporting() -> Iterator[None]:
    """The symbolics above registered for the duration of an export, removed after."""
    torch.onnx.register_custom_op_symbolic("aten::layer_norm", layer_norm_over_last_axes, 9)
    try:
        yield
    finally:
        torch.onnx.unregister_custom_op_symbolic("aten::layer_norm", 9)

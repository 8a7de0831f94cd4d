"""A pass over a traced graph that gives its number constants one dimension, so element-wise operations skip
PyTorch's scalar path.

Traced, ``x * 0.7`` becomes a product with a 0-dim constant tensor and ``x < 1.5`` a comparison with a number.
At batch 1 the per-frame graphs (:mod:`model.inference.traced_step`) are bound by per-operation dispatch, and the
scalar path costs most of such an operation: in a traced chain on the development machine a product with a 0-dim
constant took 5.6 us against 1.8 us for a product of two ``[1, 2]`` tensors, a comparison with a number about
8 us. A constant of shape ``[1]`` broadcasts instead, for the same result: it is stored in the dtype the
operation computes in (float32 for a floating constant, int64 for an integer one, as a number is promoted
against the float32 and int64 tensors of these graphs), so every value is the one the scalar path gives, to
the bit. Where the other operand is 0-dim too the result would gain a dimension, so such operations are left
alone; the per-frame graphs have none on their path (every value there has a batch dimension).
"""

from __future__ import annotations

import torch

# Element-wise operations whose operands broadcast, with a tensor overload for every scalar one (not pow: its
# scalar overload has its own kernels, which need not round as the tensor one does).
_BINARY = frozenset({"aten::mul", "aten::add", "aten::sub", "aten::div", "aten::rsub", "aten::atan2",
                     "aten::minimum", "aten::maximum", "aten::__and__", "aten::__or__"})
_COMPARISONS = frozenset({"aten::lt", "aten::gt", "aten::le", "aten::ge", "aten::eq", "aten::ne"})


def dimensioned_constants(graph: torch.Graph) -> int:
    """Rewrite ``graph`` (a frozen traced graph, before its first run) in place as the module doc says; returns
    how many operands it changed."""
    changed = 0
    for node in list(graph.nodes()):
        kind = node.kind()
        if kind not in _BINARY and kind not in _COMPARISONS:
            continue
        inputs = list(node.inputs())
        if len(inputs) < 2 or not _has_dimensions(inputs[0]):
            continue
        number = _constant_number(inputs[1])
        if number is None:
            continue
        constant = _insert_constant(graph, node, number)
        if inputs[1].type().kind() == "TensorType":  # a 0-dim tensor constant: the same overload, a new operand
            node.replaceInput(1, constant)
        else:  # a number: the operation's tensor overload, in a new node
            new = graph.create(kind, [inputs[0], constant, *inputs[2:]], 1)
            new.insertBefore(node)
            new.output().setType(node.output().type())
            node.output().replaceAllUsesWith(new.output())
            node.destroy()
        changed += 1
    torch._C._jit_pass_dce(graph)  # the replaced constants and nodes
    return changed


def _has_dimensions(value: torch.Value) -> bool:
    """Whether ``value`` is a tensor known to have at least one dimension."""
    kind = value.type()
    if not isinstance(kind, torch.TensorType):
        return False
    dims = kind.dim()
    return dims is not None and dims > 0


def _constant_number(value: torch.Value) -> torch.Tensor | None:
    """``value``'s number as a ``[1]`` tensor in the dtype its operation computes in, where it is a constant
    number or 0-dim constant tensor; else None."""
    node = value.node()
    if node.kind() != "prim::Constant" or not node.hasAttribute("value"):
        return None
    if value.type().kind() == "TensorType":
        tensor = node.t("value")
        if tensor.dim() != 0 or tensor.dtype == torch.bool:
            return None
        number: float | int = tensor.item()
    elif value.type().kind() in ("FloatType", "IntType"):
        raw = value.toIValue()
        if not isinstance(raw, (float, int)) or isinstance(raw, bool):
            return None
        number = raw
    else:
        return None
    if isinstance(number, float):
        return torch.tensor([number], dtype=torch.float32)
    return torch.tensor([number], dtype=torch.int64)


def _insert_constant(graph: torch.Graph, before: torch.Node, tensor: torch.Tensor) -> torch.Value:
    node = graph.create("prim::Constant", [], 1)
    node.t_("value", tensor)
    node.output().inferTypeFrom(tensor)
    node.insertBefore(before)
    return node.output()

"""The traced graphs' number constants given a dimension: the same values to the bit, the same shapes."""

from __future__ import annotations

import warnings

import torch

from model.inference.graph_constants import dimensioned_constants


class _Numbers(torch.nn.Module):
    """The kinds of constant operand the per-frame graphs hold: floats and ints against float and int tensors."""

    def forward(self, x: torch.Tensor, n: torch.Tensor, s: torch.Tensor) -> tuple[torch.Tensor, ...]:
        y = (x * 0.7 + 0.1) / 3.0 - 1e-4
        fade = (n.float() / 5).clamp(0.0, 1.0).view(-1, 1, 1)
        mask = (y < 0.25) & (n >= 5).view(-1, 1, 1) | (y > 1.5)
        return y, 1.0 - fade * y, mask, n - 1, x * s * 0.5, torch.atan2(y, x + 2.0)


def _traced(rewrite: bool) -> tuple[torch.jit.ScriptModule, int]:
    args = (torch.randn(3, 2, 4), torch.arange(3), torch.tensor(2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traced = torch.jit.trace(_Numbers().eval(), args, check_trace=False)
    changed = dimensioned_constants(traced.graph) if rewrite else 0
    return torch.jit.freeze(traced), changed


def test_the_rewritten_graph_gives_the_same_bits_and_shapes():
    plain, _ = _traced(False)
    rewritten, changed = _traced(True)
    assert changed >= 8  # every float and int constant but those against the 0-dim s
    gen = torch.Generator().manual_seed(0)
    for rows in (1, 3, 7):
        x = torch.randn(rows, 2, 4, generator=gen) * 3
        n = torch.randint(-2, 9, (rows,), generator=gen)
        s = torch.tensor(1.7)
        for _ in range(3):  # the profiling executor specialises after the first runs
            want, got = plain(x, n, s), rewritten(x, n, s)
        for a, b in zip(want, got):
            assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)


def test_a_number_against_a_0_dim_tensor_is_left_alone():
    class Scalarish(torch.nn.Module):
        def forward(self, s: torch.Tensor) -> torch.Tensor:
            return s * 0.5

    traced = torch.jit.trace(Scalarish().eval(), (torch.tensor(3.0),))
    assert dimensioned_constants(traced.graph) == 0
    assert torch.jit.freeze(traced)(torch.tensor(3.0)).shape == ()

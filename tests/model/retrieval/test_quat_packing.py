"""Smallest-three packing: every rotation comes back within three tenths of a degree, q and -q pack alike, and the
packed words use all 32 bits (the largest component's index in the top two)."""

from __future__ import annotations

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.retrieval.quat_packing import pack_quaternions, unpack_quaternions


def _angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return 2 * torch.acos((a * b).sum(-1).abs().clamp(max=1.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).filter(lambda q: sum(x * x for x in q) > 1e-3))
def test_any_rotation_comes_back_within_three_tenths_of_a_degree(q: list[float]) -> None:
    unit = torch.tensor(q, dtype=torch.float64)
    unit = (unit / unit.norm()).float()
    back = unpack_quaternions(pack_quaternions(unit))
    assert float(_angle(back, unit)) < math.radians(0.3)
    assert torch.equal(pack_quaternions(unit), pack_quaternions(-unit))


def test_many_at_once_and_every_index_of_the_largest() -> None:
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(5000, 22, 4, generator=gen)
    q = q / q.norm(dim=-1, keepdim=True)
    packed = pack_quaternions(q)
    assert packed.dtype == torch.int32 and packed.shape == (5000, 22)
    assert set(((packed.long() & 0xFFFFFFFF) >> 30).unique().tolist()) == {0, 1, 2, 3}
    assert float(_angle(unpack_quaternions(packed), q).max()) < math.radians(0.3)

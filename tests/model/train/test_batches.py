"""Window batches: joining two batches gives the batch of all their windows."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from model.data.synthetic import synthetic_walk
from model.train.batches import WindowBatch, make_batch
from model.train.motion_tensors import MotionTensors


def test_joined_batches_are_the_batch_of_all_their_windows() -> None:
    walks = [synthetic_walk(frames=50, cadence_hz=1.5, stride_deg=35.0, turn_deg_s=t) for t in (0.0, 40.0)]
    t = MotionTensors.from_clips([(w, 0, "walk") for w in walks], ["s"], walks[0].skeleton, augment=False, progress=False)
    n = t.positions.shape[0]
    t.phase, t.amplitude, t.frequency = torch.rand(n, 3, 2), torch.rand(n, 3), torch.rand(n, 3)
    starts, owners = t.window_starts(14, 3)
    pick = torch.tensor([0, 5, len(starts) - 1])
    whole = make_batch(t, starts[pick], owners[pick], 14, 3, with_phase=True)
    parts = [make_batch(t, starts[pick[:1]], owners[pick[:1]], 14, 3, with_phase=True),
             make_batch(t, starts[pick[1:]], owners[pick[1:]], 14, 3, with_phase=True)]
    joined = WindowBatch.cat(parts)
    for f in dataclasses.fields(WindowBatch):
        a, b = getattr(joined, f.name), getattr(whole, f.name)
        if f.name == "states":
            assert all(torch.equal(getattr(a, g), getattr(b, g)) for g in ("rel", "vel", "rot", "root_xz"))
        elif a is None:
            assert b is None
        else:
            assert torch.equal(a, b)
    mixed = dataclasses.replace(parts[0], phase=None)
    with pytest.raises(ValueError, match="phase labels"):
        WindowBatch.cat([mixed, parts[1]])

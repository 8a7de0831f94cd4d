"""Growing a sampler trained without the target-velocity flag into one that reads it.

The flag (:attr:`model.nets.sampler.SamplerConfig.target_velocity_flag`) is one more input of the
target encoder's first layer. A sampler trained without it grows a zero column there, so it computes
exactly what it did for targets given with their velocity, and a run goes on from it: from a
packaged bundle (:mod:`model.train.from_bundle`) or from the previous stage's checkpoint in the same
run folder (the shipped recipe's stage F after E3), whose optimiser moments grow zero columns too.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from model.nets.sampler import TransitionSampler
from model.train.loop import LoopConfig, make_optimizer
from model.train.sampler_stage import trained_parameters

FLAG_KEY = "target_encoder.0.weight"  # the target encoder's first layer: the flag is its last input column

Tensor = torch.Tensor


def _grow(t: Tensor, columns: int) -> Tensor:
    return torch.cat([t, t.new_zeros(t.shape[0], columns - t.shape[1])], dim=1)


def widen_state(state: dict[str, Tensor], sampler: TransitionSampler, prefix: str = "") -> dict[str, Tensor]:
    """``state`` (a sampler's state dict, keys after ``prefix``) with the flag's column added where ``sampler``
    reads it and the state does not; unchanged otherwise."""
    key = prefix + FLAG_KEY
    want = sampler.state_dict()[FLAG_KEY].shape
    if key not in state or state[key].shape == want:
        return state
    if state[key].shape[1] + 1 != want[1] or not sampler.config.target_velocity_flag:
        raise ValueError(f"{key} has shape {list(state[key].shape)}; the sampler's is {list(want)}")
    return {**state, key: _grow(state[key], want[1])}


def widen_checkpoint(folder: Path, sampler: TransitionSampler) -> bool:
    """Grow the sampler checkpoint in ``folder`` (:func:`model.train.loop.save_checkpoint`) for ``sampler`` when it
    was written without the flag; True when it did. The optimiser moments of the grown weight get zero
    columns (its parameter index is its place in the optimiser the stage builds)."""
    path, meta_path = folder / "checkpoint.safetensors", folder / "checkpoint.json"
    if not path.is_file() or not meta_path.is_file():
        return False
    tensors = load_file(str(path))
    grown = widen_state(tensors, sampler, "model.")
    if grown is tensors:
        return False
    optimizer = make_optimizer(trained_parameters(sampler), LoopConfig())  # its state ids number its parameters in order
    weight = dict(sampler.named_parameters())[FLAG_KEY]
    pid = next(i for i, p in enumerate(p for g in optimizer.param_groups for p in g["params"]) if p is weight)
    width = grown["model." + FLAG_KEY].shape[1]
    for name in ("exp_avg", "exp_avg_sq"):
        key = f"opt.{pid}.{name}"
        if key in grown:
            grown[key] = _grow(grown[key], width)
    tmp = folder / "checkpoint.safetensors.tmp"
    save_file(grown, str(tmp))
    os.replace(tmp, path)
    meta = json.loads(meta_path.read_text())
    meta.setdefault("extra", {})["grown_target_velocity_flag_at"] = meta["step"]
    meta_path.write_text(json.dumps(meta, indent=1))
    return True

"""The learning-rate schedule: warm-up, cosine, and a warm restart that leaves the first part alone."""

from __future__ import annotations

import math
from typing import cast

import pytest
import torch

from model.train.loop import LoopConfig, learning_rate


def test_cosine_from_lr_to_lr_final_after_warmup():
    cfg = LoopConfig(iterations=1000, warmup=50, lr=1e-3, lr_final=1e-5)
    assert math.isclose(learning_rate(0, cfg), 1e-3 / 50)
    assert math.isclose(learning_rate(50, cfg), 1e-3)
    assert math.isclose(learning_rate(1000, cfg), 1e-5)
    lrs = [learning_rate(s, cfg) for s in range(50, 1001)]
    assert all(a >= b for a, b in zip(lrs, lrs[1:], strict=False))


def test_warm_restart_keeps_the_first_run_and_anneals_again():
    first = LoopConfig(iterations=800, warmup=50, lr=1e-3, lr_final=1e-5)
    longer = LoopConfig(iterations=1200, warmup=50, lr=1e-3, lr_final=1e-5, restart_at=800, restart_lr=3e-4)
    # Up to the restart, exactly the schedule the finished 800-step run used: it resumes from its checkpoint.
    assert all(learning_rate(s, longer) == learning_rate(s, first) for s in range(800))
    assert math.isclose(learning_rate(800, longer), 3e-4)
    assert math.isclose(learning_rate(1200, longer), 1e-5)
    tail = [learning_rate(s, longer) for s in range(800, 1201)]
    assert all(a >= b for a, b in zip(tail, tail[1:], strict=False))
    # A restart at or past the end is no restart.
    assert learning_rate(700, LoopConfig(iterations=800, restart_at=800, restart_lr=1.0)) == learning_rate(700, first)


def test_several_warm_restarts_extend_the_previous_schedule():
    one = LoopConfig(iterations=1200, warmup=50, lr=1e-3, lr_final=1e-5, restart_at=800, restart_lr=3e-4)
    two = LoopConfig(iterations=1500, warmup=50, lr=1e-3, lr_final=1e-5, restart_at=(800, 1200), restart_lr=(3e-4, 1e-4))
    assert all(learning_rate(s, two) == learning_rate(s, one) for s in range(1200))
    assert math.isclose(learning_rate(1200, two), 1e-4)
    assert math.isclose(learning_rate(1500, two), 1e-5)
    # Lists as a JSON config gives them, in any order (lists where the fields are typed as tuples, on purpose:
    # the docstring promises lists and restarts() reads any sequence; cast says so to the type checker).
    listed = LoopConfig(iterations=1500, restart_at=cast(tuple[int, ...], [1200, 800]),
                        restart_lr=cast(tuple[float, ...], [1e-4, 3e-4]))
    assert listed.restarts() == [(800, 3e-4), (1200, 1e-4)]


def test_restart_lists_must_pair_up():
    with pytest.raises(ValueError, match="restart_lr"):
        learning_rate(900, LoopConfig(iterations=1500, restart_at=(800, 1200), restart_lr=3e-4))


def test_a_rate_multiplier_slows_only_the_named_parameters(tmp_path):
    """``lr_scales`` gives the named parameters their own groups at a fraction of the schedule's rate;
    without it the optimiser keeps its two groups (checkpoints written before it resume)."""
    from torch import nn

    from model.train.loop import make_optimizer, train_loop

    model = nn.Sequential(nn.Linear(3, 3), nn.Linear(3, 3))
    params = list(model.named_parameters())
    assert len(make_optimizer(params, LoopConfig()).param_groups) == 2
    assert len(make_optimizer(params, LoopConfig(), {"1.": 1.0}).param_groups) == 2
    groups = make_optimizer(params, LoopConfig(), {"1.": 0.25}).param_groups
    assert [g.get("lr_scale", 1.0) for g in groups] == [1.0, 1.0, 0.25, 0.25]
    assert sum(len(g["params"]) for g in groups) == 4 and {id(p) for p in groups[2]["params"]} == {id(model[1].weight)}

    before = {n: p.detach().clone() for n, p in params}

    def step(_: int) -> dict[str, float]:
        for p in model.parameters():
            p.grad = torch.ones_like(p)  # the same gradient everywhere: AdamW's first step moves each by its rate
        return {}

    cfg = LoopConfig(iterations=1, epoch_iterations=1, lr=1e-2, lr_final=1e-2, warmup=0, weight_decay=0.0)
    train_loop("toy", tmp_path / "run", model, params, cfg, step, lambda: {}, progress=False, lr_scales={"1.": 0.25})
    moved = {n: float((p.detach() - before[n]).abs().max()) for n, p in model.named_parameters()}
    assert moved["0.weight"] == pytest.approx(1e-2, rel=1e-3) and moved["1.weight"] == pytest.approx(2.5e-3, rel=1e-3)

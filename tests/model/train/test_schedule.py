"""The learning-rate schedule: warm-up, cosine, and a warm restart that leaves the first part alone."""

from __future__ import annotations

import math

import pytest

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
    # Lists as a JSON config gives them, in any order.
    assert LoopConfig(iterations=1500, restart_at=[1200, 800], restart_lr=[1e-4, 3e-4]).restarts() == [(800, 3e-4), (1200, 1e-4)]


def test_restart_lists_must_pair_up():
    with pytest.raises(ValueError, match="restart_lr"):
        learning_rate(900, LoopConfig(iterations=1500, restart_at=(800, 1200), restart_lr=3e-4))

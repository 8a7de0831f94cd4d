"""Every shipped training preset loads, and the default model's continuation presets continue it."""

from __future__ import annotations

import json

import pytest

from model.train.pipeline import TrainConfig
from rsmt_cli.train_commands import PRESET_DIR

PRESETS = sorted(PRESET_DIR.glob("*.json"))
# Chains of presets run one after the other on one run folder, in training order.
CHAINS = {
    "default": ["default", "default-continue-critics", "default-continue-accuracy"],
    # The shipped model's recipe: the two-hour presets, then the three cross-style stages.
    "shipped": ["two-hour-1-frames", "two-hour-2-critics", "two-hour-3-accuracy", "two-hour-4-accuracy",
                "cross-style-1-critics", "cross-style-2-arrival", "cross-style-3-accuracy"],
    # The same recipe with a shorter first stage and no D (tried for about two hours; not shipped).
    "fast": ["fast-1-frames", "fast-2-critics", "fast-3-accuracy", "fast-4-cross-critics",
             "fast-5-cross-arrival", "fast-6-cross-accuracy"],
}


@pytest.mark.parametrize("path", PRESETS, ids=lambda p: p.stem)
def test_every_preset_loads(path):
    cfg = TrainConfig.load(path)
    assert cfg.about and cfg.sampler_stage.loop.iterations > 0


@pytest.mark.parametrize("chain", CHAINS.values(), ids=CHAINS.keys())
def test_continuations_change_only_the_sampler_stage_and_extend_its_schedule(chain):
    raw = [json.loads((PRESET_DIR / f"{name}.json").read_text()) for name in chain]
    cfgs = [TrainConfig.load(PRESET_DIR / f"{name}.json") for name in chain]
    for before, after, a, b in zip(cfgs, cfgs[1:], raw, raw[1:]):
        # Same data, split, networks and earlier stages: the run folder's phase model and manifold stay valid.
        assert {k: v for k, v in a.items() if k not in ("name", "about", "sampler_stage")} == \
               {k: v for k, v in b.items() if k not in ("name", "about", "sampler_stage")}
        assert before.sampler_stage.loop.seed == after.sampler_stage.loop.seed
        lb, la = before.sampler_stage.loop, after.sampler_stage.loop
        assert la.iterations > lb.iterations
        # The schedule up to the earlier preset's end is unchanged; the new part starts with a restart there.
        assert la.restart_at[: len(lb.restart_at)] == lb.restart_at and la.restart_lr[: len(lb.restart_lr)] == lb.restart_lr
        assert lb.iterations in la.restart_at

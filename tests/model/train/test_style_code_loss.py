"""The style code's contrastive term: its math and a sampler stage that trains with it (the clips it draws:
test_style_pairs.py)."""

from __future__ import annotations

import json
import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from model.data.synthetic import write_synthetic_dataset
from model.train.presets import preset_dict
from model.train.recipe_chains import load_recipe
from model.train.sampler_config import SamplerStageConfig
from model.train.style_code_loss import supervised_contrastive, time_mean_code
from rsmt_cli.main import main

pytestmark = pytest.mark.usefixtures("one_thread")


def test_clustered_codes_score_lower_than_random_ones_and_reach_the_bound():
    gen = torch.Generator().manual_seed(0)
    labels = torch.arange(4).repeat_interleave(4)
    clustered = torch.nn.functional.one_hot(labels, 8).float() * 10.0
    noisy = torch.randn(16, 8, generator=gen)
    tight = supervised_contrastive(clustered, labels, 0.1).item()
    # Tight clusters: each anchor's three positives share nearly all the probability: -log(1/3).
    assert tight == pytest.approx(math.log(3), rel=1e-3)  # negatives at cosine 0 keep e^-10 of the mass
    assert supervised_contrastive(noisy, labels, 0.1).item() > tight + 1.0


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 5), st.integers(2, 4), st.floats(0.05, 1.0), st.integers(0, 10_000))
def test_the_loss_is_at_least_its_bound_and_ignores_scale_and_order(classes: int, per: int, tau: float, seed: int):
    gen = torch.Generator().manual_seed(seed)
    labels = torch.arange(classes).repeat_interleave(per)
    codes = torch.randn(len(labels), 6, generator=gen, dtype=torch.float64)
    loss = supervised_contrastive(codes, labels, tau)
    assert loss.item() >= math.log(per - 1) - 1e-9  # the mean log-probability of positives cannot beat 1/(per-1)
    assert supervised_contrastive(codes * 7.5, labels, tau).item() == pytest.approx(loss.item(), rel=1e-9, abs=1e-12)
    perm = torch.randperm(len(labels), generator=gen)
    assert supervised_contrastive(codes[perm], labels[perm], tau).item() == pytest.approx(loss.item(), rel=1e-9)


def test_a_batch_without_positives_gives_zero_with_a_gradient_and_bad_input_is_refused():
    codes = torch.randn(3, 4, requires_grad=True)
    loss = supervised_contrastive(codes, torch.tensor([0, 1, 2]), 0.1)
    assert loss.item() == 0.0
    loss.backward()
    assert codes.grad is not None
    with pytest.raises(ValueError):
        supervised_contrastive(codes, torch.tensor([0, 1]), 0.1)
    with pytest.raises(ValueError):
        supervised_contrastive(codes, torch.tensor([0, 1, 2]), 0.0)
    assert time_mean_code(torch.ones(2, 5, 3)).shape == (2, 3)


def test_settings_are_checked():
    with pytest.raises(ValueError):
        SamplerStageConfig(w_code_contrast=-1.0)
    with pytest.raises(ValueError):
        SamplerStageConfig(code_contrast_clips=1)
    with pytest.raises(ValueError):
        SamplerStageConfig(code_contrast_temperature=0.0)


def test_both_datasets_recipes_train_the_code_term_in_every_stage():
    for name in ("both-datasets", "both-datasets-smoke"):
        recipe = load_recipe(name)
        assert all(recipe.stage_config(s).sampler_stage.w_code_contrast > 0 for s in recipe.stages)
    assert all(load_recipe("default-model").stage_config(s).sampler_stage.w_code_contrast == 0
               for s in load_recipe("default-model").stages)


@pytest.mark.slow  # trains every stage (synthetic data)
def test_a_sampler_stage_with_the_term_shows_it_and_moves_the_encoder(tmp_path, monkeypatch):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    data = tmp_path / "data"
    write_synthetic_dataset(data)
    cfg = preset_dict("smoke")
    cfg["sampler_stage"].update(w_code_contrast=1.0, code_contrast_styles=3, code_contrast_clips=3)
    path = tmp_path / "code.json"
    path.write_text(json.dumps(cfg))
    args = ["train", "all", "--config", str(path), "--data", str(data), "--out", str(tmp_path / "bundle"),
            "--run", str(tmp_path / "run"), "--quiet"]
    assert main(args) == 0
    history = json.loads((tmp_path / "run" / "sampler" / "checkpoint.json").read_text())["history"]
    assert all("train_code_contrast" in h for h in history)
    assert all(math.isfinite(h["train_code_contrast"]) and h["train_code_contrast"] >= math.log(2) - 1e-6
               for h in history)

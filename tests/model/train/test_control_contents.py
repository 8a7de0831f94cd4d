"""Changed-control windows can be drawn from the takes of chosen contents (dataset 1's backward, angled and dash
gaits), and the both-datasets recipes ask for them from the first step on."""

from __future__ import annotations

import pytest
import torch

from model.data.preprocessed import load_motion_cache
from model.data.synthetic import write_synthetic_dataset
from model.train.motion_tensors import MotionTensors
from model.train.recipe_chains import load_recipe
from model.train.sampler_stage import StylePairs

pytestmark = pytest.mark.usefixtures("one_thread")


def test_style_pairs_of_some_contents_draw_only_their_windows(tmp_path) -> None:
    write_synthetic_dataset(tmp_path / "data", takes_per_pair=2, frames=90)
    cache = load_motion_cache(tmp_path / "data", root=tmp_path / "cache", workers=1, progress=False)
    tensors = MotionTensors.from_cache(cache, list(range(len(cache))))
    pairs = StylePairs(tensors, 30, 20, contents=["walk-turn-left"])
    left = tensors.contents.index("walk-turn-left")
    gen = torch.Generator().manual_seed(0)
    for _ in range(5):
        starts, owners, clips = pairs.sample(16, gen)
        assert bool((tensors.content[owners] == left).all())
    every = StylePairs(tensors, 30, 20)
    drawn = torch.cat([every.sample(16, gen)[1] for _ in range(10)])
    assert len(set(tensors.content[drawn].tolist())) > 1
    with pytest.raises(ValueError):
        StylePairs(tensors, 30, 20, contents=["walk-back"])  # no such take


@pytest.mark.parametrize("name", ["both-datasets", "both-datasets-smoke"])
def test_both_datasets_recipes_draw_changed_controls_from_the_real_gaits_from_the_start(name: str) -> None:
    recipe = load_recipe(name)
    for stage in recipe.stages:
        s = recipe.stage_config(stage).sampler_stage
        assert s.control_batch > 0 and s.control_from_start and s.loop.checkpoint_every_s == 1200
        assert set(s.control_contents) == {"walk-back", "walk-left", "walk-right", "dash"}

"""The rehearsal motion of fine-tuning: the bundle's known styles, train takes only, a few per group."""

from __future__ import annotations

import json

import pytest

from model.data.preprocessed import load_motion_cache
from model.data.synthetic import synthetic_skeleton, write_synthetic_dataset
from model.inference.bundle import Bundle
from model.train.finetune_data import TRAIN_CONFIG, rehearsal_motion


@pytest.fixture()
def data(tmp_path, monkeypatch):
    monkeypatch.setenv("RSMT_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "data"
    write_synthetic_dataset(folder, takes_per_pair=4, frames=100)
    return folder


def test_held_out_and_new_styles_are_not_rehearsed(tmp_path, data):
    bundle = Bundle.create(synthetic_skeleton())
    folder = bundle.save(tmp_path / "b")
    (folder / TRAIN_CONFIG).write_text(json.dumps({"ratios": [0.5, 0.25, 0.25], "holdout_styles": ["slow"]}))
    motion = rehearsal_motion(data, bundle, folder, "bouncy", progress=False)
    assert {motion.styles[k] for k in motion.style.unique().tolist()} == {"brisk"}
    cache = load_motion_cache(data, progress=False)
    train = {cache.takes[i].take_id for i in cache.make_split([0.5, 0.25, 0.25], ["slow"]).train}
    assert {n.removeprefix("orig:") for n in motion.names} <= train  # no val or test take


def test_a_few_takes_per_style_and_content(tmp_path, data):
    bundle = Bundle.create(synthetic_skeleton())
    folder = bundle.save(tmp_path / "b")  # no training config: the data's default split
    motion = rehearsal_motion(data, bundle, folder, "bouncy", progress=False, takes_per_group=1)
    assert len(motion.names) == 2 * 3  # two styles, three contents, one take each
    with pytest.raises(ValueError, match="no train take"):
        rehearsal_motion(data, bundle, folder, "bouncy", progress=False, takes_per_group=0)

"""Tests of training windows (counts, the last exact fit kept), the window dataset and the style-balanced sampler."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from torch.utils.data import DataLoader

from model.motion_cache import load_motion_cache
from model.windows import StyleBalancedBatchSampler, WindowDataset, make_windows, window_starts
from tests.model.test_takes import NUM_JOINTS, make_bandai_tree


@pytest.mark.parametrize("frames, length, overlap, starts", [
    (61, 61, 21, [0]),  # the exact fit is kept (the reference code drops it)
    (60, 61, 21, []),
    (100, 61, 21, [0]),
    (101, 61, 21, [0, 40]),
    (120, 120, 0, [0]),
    (239, 120, 0, [0]),
    (240, 120, 0, [0, 120]),
    (0, 10, 0, []),
    (10, 1, 0, list(range(10))),
])
def test_window_starts(frames: int, length: int, overlap: int, starts: list[int]) -> None:
    assert list(window_starts(frames, length, overlap)) == starts


@pytest.mark.parametrize("length, overlap", [(0, 0), (10, 10), (10, -1)])
def test_window_starts_rejects(length: int, overlap: int) -> None:
    with pytest.raises(ValueError):
        window_starts(100, length, overlap)


@given(n=st.integers(0, 500), length=st.integers(1, 130), data=st.data())
def test_every_window_fits_and_none_is_missed(n: int, length: int, data: st.DataObject) -> None:
    overlap = data.draw(st.integers(0, length - 1))
    step = length - overlap
    starts = list(window_starts(n, length, overlap))
    assert all(s + length <= n for s in starts)
    assert starts == [i * step for i in range(len(starts))]
    assert (starts[-1] if starts else -step) + step + length > n  # the next one would not fit
    assert len(starts) == (max(0, (n - length) // step + 1) if n >= length else 0)


def test_make_windows_over_takes() -> None:
    assert make_windows([5, 10, 3], 4, 2) == [(0, 0), (1, 0), (1, 2), (1, 4), (1, 6)]
    assert make_windows([5, 10, 3], 4, 2, takes=[2, 0]) == [(0, 0)]


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("windows")
    make_bandai_tree(root / "data", takes_per_group=3, frames=40)  # 41..43 frames per take
    return load_motion_cache(root / "data", root=root / "cache", workers=1, progress=False)


def test_window_dataset(cache) -> None:
    dataset = WindowDataset(cache, length=20, overlap=5)
    expected = sum(len(window_starts(n, 20, 5)) for n in cache.frame_counts)
    assert len(dataset) == expected == 18 * 2
    item = dataset[3]
    take, start = dataset.windows[3]
    assert item["rotations"].shape == (20, NUM_JOINTS, 4) and item["root_positions"].shape == (20, 3)
    assert item["offsets"].shape == (NUM_JOINTS, 3)
    torch.testing.assert_close(item["rotations"], cache.rotations(take)[start:start + 20])
    assert (item["take"], item["start"]) == (take, start)
    assert item["style"] == cache.style_id(take) and item["content"] == cache.content_id(take)
    assert cache.styles[item["style"]] == cache.takes[take].style

    train = WindowDataset(cache, length=20, overlap=5, takes=cache.split.train)
    assert {t for t, _ in train.windows} <= set(cache.split.train)
    loader = DataLoader(train, batch_size=4)
    batch = next(iter(loader))
    assert batch["rotations"].shape == (4, 20, NUM_JOINTS, 4)
    assert batch["style"].shape == (4,)


def test_sampler_batches_one_style_each_and_styles_equally() -> None:
    styles = [0] * 100 + [1] * 10 + [2] * 30
    sampler = StyleBalancedBatchSampler(styles, batch_size=8)
    assert sampler.batches_per_style == 6  # ceil(140 / (8 * 3)): an epoch is about one pass over the data
    batches = list(sampler)
    assert len(batches) == len(sampler) == 18
    per_style = Counter()
    for batch in batches:
        assert len(batch) == 8
        assert len({styles[i] for i in batch}) == 1
        per_style[styles[batch[0]]] += 1
    assert per_style == {0: 6, 1: 6, 2: 6}


def test_sampler_is_deterministic_and_walks_through_large_styles() -> None:
    styles = [0] * 100 + [1] * 10
    sampler = StyleBalancedBatchSampler(styles, batch_size=10, batches_per_style=2, seed=3)
    epoch0 = list(sampler)
    assert list(StyleBalancedBatchSampler(styles, batch_size=10, batches_per_style=2, seed=3)) == epoch0
    seen = set()
    for epoch in range(5):  # style 0 gives 20 windows per epoch: all 100 in 5 epochs, none repeated
        sampler.set_epoch(epoch)
        for batch in sampler:
            if styles[batch[0]] == 0:
                assert not seen & set(batch)
                seen |= set(batch)
    assert seen == set(range(100))
    sampler.set_epoch(1)
    assert list(sampler) != epoch0


def test_sampler_small_style_and_empty() -> None:
    sampler = StyleBalancedBatchSampler([0] * 3 + [1] * 20, batch_size=8, batches_per_style=1)
    small = next(b for b in sampler if b[0] < 3)
    assert len(small) == 8 and set(small) == {0, 1, 2}  # repeats inside the batch
    assert list(StyleBalancedBatchSampler([], batch_size=4)) == []
    with pytest.raises(ValueError):
        StyleBalancedBatchSampler([0], batch_size=0)


def test_sampler_with_the_dataset(cache) -> None:
    dataset = WindowDataset(cache, length=10, overlap=0)
    sampler = StyleBalancedBatchSampler(dataset.window_styles, batch_size=4, seed=1)
    loader = DataLoader(dataset, batch_sampler=sampler)
    for batch in loader:
        assert batch["style"].unique().numel() == 1
        assert batch["rotations"].shape == (4, 10, NUM_JOINTS, 4)


def test_dataset_refuses_mixed_rigs(tmp_path: Path) -> None:
    from tests.model.test_takes import write_bvh

    write_bvh(tmp_path / "d" / "dataset-2_walk_a_001.bvh")
    write_bvh(tmp_path / "d" / "dataset-2_walk_a_002.bvh", names={"Spine": "Chest"})
    cache = load_motion_cache(tmp_path / "d", root=tmp_path / "c", workers=1, progress=False)
    assert len(cache) == 2
    with pytest.raises(ValueError, match="different rigs"):
        WindowDataset(cache, length=10)
    assert len(WindowDataset(cache, length=10, takes=[1])) == 4

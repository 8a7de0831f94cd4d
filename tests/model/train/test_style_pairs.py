"""The sampler stage's style draws (StylePairs): clip sets of distinct styles and cross-style pairs."""

from __future__ import annotations

import torch

from model.data.synthetic import SYNTHETIC_STYLES, synthetic_walk
from model.train.motion_tensors import MotionTensors
from model.train.sampler_stage import StylePairs


def _six_walks() -> tuple[MotionTensors, StylePairs]:
    """Six 80-frame synthetic walks of increasing speed, the styles taken in turn, and their 30-frame pairs."""
    styles = list(SYNTHETIC_STYLES)
    clips = [(synthetic_walk(frames=80, speed_cm_s=100.0 + 10 * i), i % len(styles), "walk") for i in range(6)]
    tensors = MotionTensors.from_clips(clips, styles, clips[0][0].skeleton, None, augment=False, seed=0, progress=False)
    return tensors, StylePairs(tensors, 30, 20)


def test_clip_sets_hold_distinct_styles_each_with_its_own_clips():
    tensors, pairs = _six_walks()
    gen = torch.Generator().manual_seed(0)
    starts, ids = pairs.sample_clip_sets(8, 3, gen)  # more styles asked than there are: all of them
    assert len(starts) == 3 * len(pairs.styles) and sorted(set(ids.tolist())) == pairs.styles
    owner = torch.searchsorted(tensors.take_start, starts, right=True) - 1
    assert torch.equal(tensors.style[owner], ids)


def test_cross_style_pairs_differ_in_style():
    tensors, pairs = _six_walks()
    gen = torch.Generator().manual_seed(0)
    starts_of_take = tensors.take_start
    for _ in range(10):
        starts, owners, clip_starts, style = pairs.sample_cross(6, gen)
        assert (tensors.style[owners] != style).all()
        assert ((starts >= starts_of_take[owners]) & (starts + 30 <= starts_of_take[owners] + tensors.take_len[owners])).all()
        clip_owner = torch.searchsorted(starts_of_take, clip_starts, right=True) - 1
        assert (tensors.style[clip_owner] == style).all()

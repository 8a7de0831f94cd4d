"""The motion a fine-tuning run rehearses: the styles a bundle was trained on, from its own data.

The bundle's ``train_config.json`` (saved beside every trained bundle) gives the frame rate, rig
profile, split ratios and held-out styles of its training; the takes rehearsed are that split's
train takes, less the held-out styles and the style being added, so a fine-tuning run never sees a
validation or test take, nor a style the bundle did not know. A few takes of each style and content
are enough for a few hundred steps (the first ones by take id, so every run rehearses the same).
"""

from __future__ import annotations

import json
from pathlib import Path

from model.data.preprocessed import load_motion_cache
from model.inference.bundle import Bundle
from model.train.motion_tensors import MotionTensors

TRAIN_CONFIG = "train_config.json"
TAKES_PER_GROUP = 4  # takes rehearsed per (style, content)


def rehearsal_motion(data: Path, bundle: Bundle, bundle_dir: Path, new_style: str, progress: bool = True,
                     takes_per_group: int = TAKES_PER_GROUP) -> MotionTensors:
    """Motion tensors of the known styles' train takes in ``data`` (see the module doc)."""
    path = Path(bundle_dir) / TRAIN_CONFIG
    trained = json.loads(path.read_text()) if path.is_file() else {}
    held = tuple(trained.get("holdout_styles", ()))
    cache = load_motion_cache(data, fps=bundle.config.fps, profile=trained.get("profile"), progress=progress)
    split = cache.make_split(trained["ratios"], held) if "ratios" in trained else cache.split
    groups: dict[tuple[str, str], list[int]] = {}
    for i in sorted(split.train, key=lambda k: cache.takes[k].take_id):
        take = cache.takes[i]
        if take.style != new_style and take.style not in held:
            groups.setdefault((take.style, take.content), []).append(i)
    takes = sorted(i for members in groups.values() for i in members[:takes_per_group])
    if not takes:
        raise ValueError(f"{data}: no train take of a style the bundle knows besides {new_style!r} to rehearse")
    return MotionTensors.from_cache(cache, takes, bundle.skeleton, augment=False, progress=progress)

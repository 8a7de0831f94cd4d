"""Style clips for built-in styles picked from a motion dataset: one walking clip per style, from the train split only.

The rule is fixed, so the same data gives the same clips on every machine: for each style, the train
takes of the content ``walk`` in ``take_id`` order; the first one long enough gives its middle
``frames`` frames (the walk at its steady pace, clear of the first and last steps). The split is the
preprocessed cache's default split, the one training uses, so no val or test take is ever picked.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from model.data.preprocessed import load_motion_cache
from model.motion.clip import Clip

DEFAULT_FRAMES = 180  # 6 s at 30 fps: inside the default model's 16-240 style frames, several gait cycles
DEFAULT_CONTENT = "walk"


@dataclass(frozen=True)
class StylePick:
    """One style's clip as the data holds it (on the data's rig, at the fps asked for), the take it is cut
    from and where (``source``); a bundle puts it on its rig (:func:`model.inference.bundle_styles.clip_on_rig`)."""

    style: str
    clip: Clip
    take_id: str
    source: str


class NoStyleClip(ValueError):
    """A style of the data has no train take long enough to give a clip."""


def pick_style_clips(data: Path, fps: float, frames: int = DEFAULT_FRAMES, content: str = DEFAULT_CONTENT,
                     workers: int = 1) -> list[StylePick]:
    """One clip of ``frames`` frames per style of the data, at ``fps`` (see the module doc)."""
    cache = load_motion_cache(data, fps=fps, workers=workers, progress=False)
    train = sorted(cache.split.train, key=lambda i: cache.takes[i].take_id)
    picks: list[StylePick] = []
    for style in cache.styles:
        candidates = [i for i in train if cache.takes[i].style == style and cache.takes[i].content == content]
        long_enough = [i for i in candidates if cache.num_frames(i) >= frames]
        if not long_enough:
            raise NoStyleClip(f"{data}: no train take of style {style!r} and content {content!r} has {frames} "
                                   f"frames at {fps:g} fps ({len(candidates)} shorter ones)")
        i = long_enough[0]
        start = (cache.num_frames(i) - frames) // 2
        take = cache.takes[i]
        picks.append(StylePick(style, cache.clip(i).window(start, start + frames), take.take_id,
                               f"{take.take_id} frames {start}-{start + frames} at {fps:g} fps (train split)"))
    return picks

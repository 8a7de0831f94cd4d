"""The capture's gait limits per style (:class:`model.motion.gait_limits.GaitLimits`), measured on a data set's train split.

Only real takes are read (the cache holds no mirrored or time-rescaled copies: those are made in training),
and only the train split, the takes the model learnt from. The hips are the rig's root joint; speeds are
horizontal, frame to frame at the cache's rate; the feet's lift is read on the takes' joint positions
(forward kinematics).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from model.data.preprocessed import MotionCache, ProfileArg, load_motion_cache
from model.motion import gait
from model.motion.gait_limits import GaitLimits, StyleGait, gait_of
from model.motion.kinematics import forward_kinematics
from model.motion.planted_feet import planted_rise
from model.motion.rotations import quat_normalize

P99 = 0.99


def measure_gait_limits(cache: MotionCache, takes: list[int] | None = None) -> GaitLimits:
    """The limits of every style of ``cache`` over ``takes`` (default: its train split)."""
    chosen = sorted(cache.split.train if takes is None else takes)
    speeds: dict[str, list[torch.Tensor]] = {}
    heights: dict[str, dict[str, list[float]]] = {}
    counts: dict[str, int] = {}
    lifts: dict[str, float] = {}
    rises: dict[str, float] = {}
    for i in chosen:
        take = cache.takes[i]
        hips = cache.root_positions(i).double()  # the root joint is the hips (the rig's first joint)
        if hips.shape[0] < 2:
            continue
        speed = (hips[1:] - hips[:-1])[:, [0, 2]].norm(dim=-1) * cache.fps
        speeds.setdefault(take.style, []).append(speed)
        lo_hi = heights.setdefault(take.style, {}).setdefault(gait_of(take.content), [])
        lo_hi.extend([float(hips[:, 1].min()), float(hips[:, 1].max())])
        counts[take.style] = counts.get(take.style, 0) + 1
        sk = cache.skeleton(i)
        pos, _ = forward_kinematics(quat_normalize(cache.rotations(i).float()), cache.root_positions(i).float(),
                                    sk.offsets_tensor(), sk.parents)
        lowest = pos[:, list(sk.feet), 1].amin(dim=-1)  # each frame's lowest foot joint
        lifts[take.style] = max(lifts.get(take.style, 0.0), float(lowest.max() - lowest.min()))
        rise = planted_rise(pos, (sk.roles.left_foot, sk.roles.right_foot), cache.fps)
        rises[take.style] = max(rises.get(take.style, 0.0), rise)
    if not speeds:
        raise ValueError(f"{cache.folder}: no take of {len(chosen)} has two frames to measure a speed on")
    styles = {}
    for style, parts in speeds.items():
        every = torch.cat(parts)
        moving = every[every > gait.MOVING_CM_S]
        p99 = float(torch.quantile(moving, P99)) if len(moving) else float(every.max())
        styles[style] = StyleGait(float(every.max()), p99,
                                  {g: (min(v), max(v)) for g, v in heights[style].items()}, counts[style],
                                  lifts[style], rises[style])
    source = f"{cache.data_root.name}: train split, {sum(counts.values())} takes at {cache.fps:g} fps"
    return GaitLimits(styles, source, cache.fps)


def gait_limits_from_data(data: Path, fps: float, workers: int = 1, *, profile: ProfileArg = None,
                          manifest: Path | None = None, units: str | float = "auto", ratios: Sequence[float] | None = None,
                          holdout_styles: Sequence[str] = ()) -> GaitLimits:
    """:func:`measure_gait_limits` of the data folder(s) ``data`` (its preprocessed cache, built when missing), read
    with that rig ``profile``, ``manifest`` and ``units``, over the train split of those ``ratios`` and
    ``holdout_styles`` (default: the cache's own split)."""
    cache = load_motion_cache(data, fps=fps, profile=profile, manifest=manifest, workers=workers, progress=False,
                              units=units)
    if ratios is None and not holdout_styles:
        return measure_gait_limits(cache)
    split = cache.make_split(holdout_styles=holdout_styles) if ratios is None else cache.make_split(ratios, holdout_styles)
    return measure_gait_limits(cache, list(split.train))

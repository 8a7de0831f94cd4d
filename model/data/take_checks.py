"""Per-take checks of floor level and facing, for a data set whose conventions are not assumed to match another's.

For every take of a cache: the toes' rest height (:func:`model.motion.gait.toe_rest_height`), the
lowest toe height, the hips' median height, the median angle between the hips' travel and the body's
facing over the frames where the hips move faster than 30 cm/s (0: forward, 180: backward; signed, left
positive) and the backward share of those frames. :func:`summarise` gives the medians per source and
content, which is what ``rsmt data inspect --cache --checks`` prints.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch

from model.data.preprocessed import MotionCache
from model.motion import gait
from model.motion.features import facing_directions
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize


def take_check(positions: torch.Tensor, skeleton: Any, fps: float) -> dict[str, float]:
    """The checks of one take's global positions ``[T, J, 3]`` (see the module docstring)."""
    toes = gait.toe_joints(skeleton)
    root = skeleton.roles.root
    hips = positions[:, root]
    step = (hips[1:] - hips[:-1])[:, [0, 2]]
    facing = facing_directions(positions[1:], skeleton)[:, [0, 2]]
    fast = step.norm(dim=-1) * fps > gait.MOVING_CM_S
    angle = torch.atan2(facing[:, 0] * step[:, 1] - facing[:, 1] * step[:, 0], (facing * step).sum(-1))
    share = gait.backward_share(positions.unsqueeze(0), skeleton, fps)[0]
    return {
        "toe_rest_cm": gait.toe_rest_height(positions, toes),
        "toe_lowest_cm": float(positions[:, list(toes), 1].min()),
        "hips_median_cm": float(hips[:, 1].median()),
        "travel_vs_facing_deg": float(torch.rad2deg(angle[fast]).median()) if bool(fast.any()) else math.nan,
        "backward_share": float(share),
    }


def check_takes(cache: MotionCache, takes: Sequence[int] | None = None) -> list[dict[str, Any]]:
    """:func:`take_check` of each take, with its id, source, style and content."""
    rows = []
    for i in range(len(cache)) if takes is None else takes:
        sk = cache.skeleton(i)
        pos, _ = forward_kinematics(quat_normalize(cache.rotations(i).float()), cache.root_positions(i).float(),
                                    sk.offsets_tensor().float(), sk.parents)
        t = cache.takes[i]
        rows.append({"take": t.take_id, "source": t.source, "style": t.style, "content": t.content,
                     **take_check(pos, sk, cache.fps)})
    return rows


def summarise(rows: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Medians of the checks per ``source/content``."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(f"{r['source'] or '-'}/{r['content']}", []).append(r)
    keys = ("toe_rest_cm", "toe_lowest_cm", "hips_median_cm", "travel_vs_facing_deg", "backward_share")
    out = {}
    for name, members in sorted(groups.items()):
        out[name] = {"takes": float(len(members))}
        for k in keys:
            values = torch.tensor([m[k] for m in members if not math.isnan(m[k])])
            out[name][k] = float(values.median()) if len(values) else math.nan
    return out

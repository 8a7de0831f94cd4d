"""Real and interpolated windows of takes for training and checking a sequence judge (:mod:`model.evaluation.sequence_judge`).

An interpolated window keeps a real window's first and last poses and slerps every joint's local
rotation (and lerps the root) between them: a judge that reads style from motion, not from posture,
should read these near chance.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from model.data.preprocessed import MotionCache
from model.evaluation.baselines import interpolate
from model.evaluation.sequence_judge import WINDOW, SequenceJudge
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_make_continuous, quat_normalize

Tensor = torch.Tensor


def real_windows(cache: MotionCache, takes: Sequence[int], step: int = 10,
                 interpolated: bool = False) -> tuple[Tensor, list[str], list[str]]:
    """``(global positions [N, WINDOW, J, 3], style per window, content per window)`` of every window ``step``
    frames apart of ``takes``; with ``interpolated`` the windows' in-betweens are interpolated (module docstring)."""
    out: list[Tensor] = []
    styles: list[str] = []
    contents: list[str] = []
    for i in takes:
        n = cache.num_frames(i)
        starts = list(range(0, n - WINDOW + 1, step))
        if not starts:
            continue
        sk = cache.skeleton(i)
        rot = quat_make_continuous(quat_normalize(cache.rotations(i).float()), dim=0)
        root = cache.root_positions(i).float()
        r = torch.stack([rot[s:s + WINDOW] for s in starts])
        p = torch.stack([root[s:s + WINDOW] for s in starts])
        if interpolated:
            mid_r, mid_p = interpolate(r[:, 0], p[:, 0], r[:, -1], p[:, -1], WINDOW - 1)
            r = torch.cat([r[:, :1], mid_r], 1)
            p = torch.cat([p[:, :1], mid_p], 1)
        pos, _ = forward_kinematics(r, p, sk.offsets_tensor().float(), sk.parents)
        out.append(pos)
        styles += [cache.takes[i].style] * len(starts)
        contents += [cache.takes[i].content] * len(starts)
    if not out:
        raise ValueError(f"no take has the {WINDOW} frames of a judge window")
    return torch.cat(out), styles, contents


def _accuracy(judge: SequenceJudge, windows: Tensor, styles: Sequence[str]) -> Tensor:
    index = {s: k for k, s in enumerate(judge.styles)}
    labels = torch.tensor([index.get(s, -1) for s in styles])
    votes = torch.cat([judge.predict(windows[lo:lo + 512]) for lo in range(0, len(windows), 512)])
    return (votes == labels).double()


def judge_report(judge: SequenceJudge, cache: MotionCache, takes: Sequence[int], step: int = 10) -> dict[str, Any]:
    """The judge's accuracy on the real windows of ``takes`` (overall, per style, per content) and on their
    interpolated copies."""
    windows, styles, contents = real_windows(cache, takes, step)
    hit = _accuracy(judge, windows, styles)
    interp, istyles, _ = real_windows(cache, takes, step, interpolated=True)
    ihit = _accuracy(judge, interp, istyles)

    def acc(mask: list[bool]) -> float | None:
        m = torch.tensor(mask)
        return float(hit[m].mean()) if bool(m.any()) else None

    return {"windows": len(styles), "accuracy": float(hit.mean()), "interpolated_accuracy": float(ihit.mean()),
            "chance": 1.0 / len(judge.styles),
            "per_style": {s: acc([x == s for x in styles]) for s in sorted(set(styles))},
            "per_content": {c: acc([x == c for x in contents]) for c in sorted(set(contents))}}

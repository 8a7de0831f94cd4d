"""The stream yardstick: a character retargeted mid-motion, as a game's stream does it.

Each locomotion case starts as the 40-frame transition to its own target (one target frame, as a
game sends it); at frame ``at`` the stream is retargeted to the same target moved 1 m sideways
(the evaluation's ``gap40-side1m`` target), keeping the arrival time. Scored: the mean joint
distance of the last frame to the moved target (arrival, cm), beside the arrival of the same
transition sent to the moved target from the start, and the largest root speed (a correction that
teleports shows there). A method run with exact arrival streams with it too (the service's
``exact_arrival`` request field), so its retargeted arrival is the bent one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from model.evaluation.cases import CaseSet, variant
from model.evaluation.methods import BundleMethod
from model.inference.engine import Character, CharacterBatch

Tensor = torch.Tensor


@dataclass(frozen=True)
class RetargetSettings:
    frames: int = 40  # frames of the transition
    at: int = 20  # frames streamed before the retarget
    target_frames: int = 1  # frames of each target sent (1: the target frame alone)


def stream(method: BundleMethod, cases: CaseSet, settings: RetargetSettings, retarget: bool,
           at: Sequence[int] | None = None) -> tuple[Tensor, Tensor]:
    """Every case streamed in one batch, retargeted when ``retarget`` at ``settings.at`` (or at ``at[b]`` for
    case ``b``: the frame from which the moved target applies); ``(rotations, roots)``."""
    frames_at = [settings.at] * len(cases) if at is None else list(at)
    if len(frames_at) != len(cases) or not all(0 < a < settings.frames for a in frames_at):
        raise ValueError(f"one retarget frame per case, each inside the transition (1..{settings.frames - 1})")
    engine = method.engine
    first = variant("gap40")
    moved = variant("gap40-side1m")
    start = moved if not retarget else first
    batch = CharacterBatch(engine)
    chars: list[Character] = []
    for b in range(len(cases)):
        style, _ = engine.encode_style(cases.style_clips[b])
        ch = engine.prepare(cases.context_clip(b), cases.target_clip(b, start, settings.target_frames), settings.frames,
                            style, deterministic=True, character_id=cases.cases[b].id,
                            exact_arrival=method.exact_arrival)
        batch.add(ch)
        chars.append(ch)
    rots: dict[str, list[Tensor]] = {c.id: [] for c in chars}
    roots: dict[str, list[Tensor]] = {c.id: [] for c in chars}
    for frame in range(settings.frames):
        for b, ch in enumerate(chars):
            if retarget and frame == frames_at[b]:
                engine.retarget(ch, batch, target=cases.target_clip(b, moved, settings.target_frames))
        out = batch.step()
        for i, ch in enumerate(out.characters):
            rots[ch.id].append(out.rotations[i])
            roots[ch.id].append(out.root_positions[i])
        batch.drop_finished()
    return (torch.stack([torch.stack(rots[c.id]) for c in chars]).float(),
            torch.stack([torch.stack(roots[c.id]) for c in chars]).float())


def retarget_report(method: BundleMethod, cases: CaseSet, settings: RetargetSettings | None = None) -> dict[str, Any]:
    """Arrival at the moved target, retargeted mid-stream and sent from the start, over ``cases``."""
    settings = settings or RetargetSettings()
    if not 0 < settings.at < settings.frames:
        raise ValueError(f"the retarget frame must fall inside the transition (1..{settings.frames - 1})")
    target = cases.target_positions(variant("gap40-side1m"))
    out: dict[str, Any] = {"cases": len(cases), "frames": settings.frames, "retarget_at": settings.at,
                           "target_frames": settings.target_frames, "moved_cm": variant("gap40-side1m").side,
                           "exact_arrival": method.exact_arrival}
    for name, retarget in (("retargeted", True), ("from_start", False)):
        rot, root = stream(method, cases, settings, retarget)
        pos, _ = cases.forward(rot, root)
        err = (pos[:, -1] - target).norm(dim=-1).mean(-1)
        speed = (root[:, 1:, [0, 2]] - root[:, :-1, [0, 2]]).norm(dim=-1).amax(1) * cases.fps
        out[name] = {"arrival_cm": round(float(err.mean()), 2), "arrival_cm_median": round(float(err.median()), 2),
                     "arrival_cm_p90": round(float(err.quantile(0.9)), 2),
                     "max_root_speed_cm_s": round(float(speed.mean()), 1),
                     "max_root_speed_cm_s_worst": round(float(speed.max()), 1)}
    return out

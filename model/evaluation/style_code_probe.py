"""How well a bundle's style encoder tells styles apart: its codes of real clips, per style.

Every clip (windows of the takes of a split) is encoded by the bundle's style encoder and averaged
over time to one vector; the vectors are centred and scaled by one common factor (Euclidean
distances as in the code space itself, in no particular unit). Scored per style:

* **leave-one-take-out nearest centroid**: each clip is given the style whose centroid is nearest,
  its own style's centroid made without any clip of its take; the share given its own style, and what it is read as
  otherwise (a row of the confusion matrix);
* **separation**: the distance from the style's centroid to the nearest other style's centroid, over
  the mean distance of its clips to their own centroid (above 1: the style sits apart from the others).

This reads the code space alone, before any decoder: a style the model never trained on that the
encoder still separates has room there, and where the motion does not follow, the limit lies in what
the rest of the network learned to do with codes (trained toward the critics' classes), not in the
encoder's capacity.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

from model.inference.engine import Engine
from model.motion.clip import Clip

Tensor = torch.Tensor


@dataclass(frozen=True)
class StyleProbe:
    """Per style: clips, leave-one-out accuracy, what it is read as, separation."""

    styles: list[str]
    clips: dict[str, int]
    accuracy: dict[str, float]
    read_as: dict[str, dict[str, float]]
    separation: dict[str, float]
    nearest: dict[str, str]

    def to_dict(self) -> dict:
        return {"styles": self.styles, "clips": self.clips, "accuracy": self.accuracy, "read_as": self.read_as,
                "separation": self.separation, "nearest": self.nearest}


def encode_clips(engine: Engine, clips: Sequence[Clip]) -> Tensor:
    """One code vector ``[N, C]`` per clip: the style encoder's code averaged over its time steps."""
    return torch.stack([engine.style_code(engine.conform(clip, "style clip")).mean(dim=1).squeeze(0).float()
                        for clip in clips])


def probe_codes(codes: Tensor, labels: Sequence[str], groups: Sequence[str] | None = None) -> StyleProbe:
    """Score code vectors ``[N, C]`` with their styles. ``groups`` (e.g. the take of each clip) are left out
    together: a clip's own centroid is made without any clip of its group, so overlapping windows of one
    take do not vouch for each other. Every style needs clips of at least two groups."""
    if codes.ndim != 2 or codes.shape[0] != len(labels):
        raise ValueError(f"need codes [N, C] and a style per row; got {tuple(codes.shape)} and {len(labels)} styles")
    groups = [str(i) for i in range(len(labels))] if groups is None else list(groups)
    if len(groups) != len(labels):
        raise ValueError(f"need a group per clip; got {len(groups)} for {len(labels)} clips")
    styles = sorted(set(labels))
    counts = {s: sum(1 for x in labels if x == s) for s in styles}
    group_style = dict(zip(groups, labels, strict=True))
    if any(group_style[g] != s for g, s in zip(groups, labels, strict=True)):
        raise ValueError("a group's clips must share one style")
    per_style = {s: sum(1 for t in group_style.values() if t == s) for s in styles}
    if len(styles) < 2 or min(per_style.values()) < 2:
        raise ValueError(f"need two styles or more with clips of at least two groups each; got {per_style}")
    x = codes.double()
    x = x - x.mean(dim=0)
    x = x / x.square().mean().sqrt().clamp_min(1e-12)  # one scale for every dimension: the space as the network reads it
    label = torch.tensor([styles.index(s) for s in labels])
    onehot = torch.nn.functional.one_hot(label, len(styles)).double()  # [N, S]
    sums = onehot.T @ x  # [S, C]
    n = onehot.sum(dim=0)  # [S]
    centroids = sums / n.unsqueeze(1)
    # Leave the clip's group out: its own style centroid without any clip of that group.
    names = sorted(set(groups))
    group = torch.tensor([names.index(g) for g in groups])
    member = torch.nn.functional.one_hot(group, len(names)).double()  # [N, G]
    group_sums, group_n = (member.T @ x)[group], member.sum(dim=0)[group]
    dist = torch.cdist(x, centroids)  # [N, S]
    own = (sums[label] - group_sums) / (n[label] - group_n).unsqueeze(1)
    dist[torch.arange(len(labels)), label] = (x - own).norm(dim=1)
    votes = dist.argmin(dim=1)
    accuracy, read_as, separation, nearest = {}, {}, {}, {}
    between = torch.cdist(centroids, centroids)
    between.fill_diagonal_(float("inf"))
    for k, s in enumerate(styles):
        mine = label == k
        accuracy[s] = float((votes[mine] == k).double().mean())
        read_as[s] = {t: float((votes[mine] == j).double().mean()) for j, t in enumerate(styles)}
        spread = (x[mine] - centroids[k]).norm(dim=1).mean()
        j = int(between[k].argmin())
        separation[s] = float(between[k, j] / spread.clamp_min(1e-12))
        nearest[s] = styles[j]
    return StyleProbe(styles, counts, accuracy, read_as, separation, nearest)


def probe_table(name: str, probe: StyleProbe) -> list[str]:
    """Markdown lines: a row per style."""
    lines = [f"Style codes of {name} (nearest centroid, each take left out of its own; separation: nearest other "
             "centroid over the style's own spread):", "",
             "| style | clips | read as itself | read as most often otherwise | separation | nearest style |",
             "|---|---|---|---|---|---|"]
    for s in probe.styles:
        others = {t: v for t, v in probe.read_as[s].items() if t != s}
        top = max(others, key=lambda t: others[t])
        otherwise = f"{top} {others[top]:.3f}" if others[top] > 0 else "–"
        lines.append(f"| {s} | {probe.clips[s]} | {probe.accuracy[s]:.3f} | {otherwise} | "
                     f"{probe.separation[s]:.2f} | {probe.nearest[s]} |")
    return lines + [""]

"""The sequence judge: a second style judge for evaluation, of another family than :mod:`model.evaluation.style_judge`.

The first judge is a linear model on whole-window summary statistics. This one is a small dilated
temporal convolution network that reads a window frame by frame, so it sees the rhythm and order of
the motion, which summary statistics average away. Its input is chosen so that no training critic
shares it: the critics (:mod:`model.nets.style_classifier`, the training's style critics) read each
frame's joint positions, velocities and rotations in the facing frame. The judge reads, per frame
step, only quantities that are unchanged by a turn about the vertical, a move on the ground and a
mirror of the walking direction, and that carry no posture:

* the rate of change (cm/s) of the distance between every pair of :func:`key_joints` (8 joints, 28
  pairs: how the limbs open and close, not where they are);
* each joint's speed relative to the root (cm/s);
* the root's horizontal speed and its vertical velocity (cm/s).

A window is :data:`WINDOW` poses (41: the last context frame and a 40-frame transition; 40 steps).
A longer sequence is scored as the mean log-probability of its windows 20 frames apart, a shorter
one (at least 3 poses) as one window. Trained on real windows of every take of the training split
(both data sets when both are given, the backward takes included), each style drawn equally often and,
within a style, each content (walk, walk-back, dash, ...) equally often, so a minute of backward walking
counts as much as half an hour of forward walking (optionally a share of them played backwards in time).
Beside them it sees the same windows with their
in-betweens interpolated (first and last poses kept) and is asked to read those as no style at all (a
uniform answer): a style is then read from how the frames between two poses move, not from the poses.

Stored as ``sequence_judge.json`` (styles, joints, the standardisation, the training record) and
``weights.safetensors``; no pickle.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import nn

from model.evaluation.style_judge import WINDOW, JudgeFolder, window_starts  # the same windows as the first judge scores
from model.motion.skeleton import Skeleton
from model.retrieval.matching import key_joints

Tensor = torch.Tensor

FORMAT = "rsmt-sequence-judge/1"
KIND = ("dilated temporal convolution network over per-frame rates of change of key-joint pair distances, joint "
        "speeds relative to the root and the root's horizontal speed and vertical velocity; no postures, no facing-frame "
        "vectors (no training critic reads these inputs)")


def step_features(positions: Tensor, skeleton: Skeleton, fps: float) -> Tensor:
    """``[B, T-1, C]`` per-step inputs of sequences of global positions ``[B, T, J, 3]`` (see the module docstring)."""
    if positions.dim() != 4 or positions.shape[1] < 2:
        raise ValueError(f"positions must be [B, T>=2, J, 3], got {list(positions.shape)}")
    p = positions.float()
    keys = key_joints(skeleton)
    k = p[:, :, keys]
    i, j = torch.triu_indices(len(keys), len(keys), offset=1)
    dist = (k[:, :, i] - k[:, :, j]).norm(dim=-1)  # [B, T, P]
    rate = (dist[:, 1:] - dist[:, :-1]) * fps
    vel = (p[:, 1:] - p[:, :-1]) * fps  # [B, T-1, J, 3]
    root = skeleton.roles.root
    relative = (vel - vel[:, :, root:root + 1]).norm(dim=-1)
    root_h = vel[:, :, root, [0, 2]].norm(dim=-1, keepdim=True)
    root_v = vel[:, :, root, 1:2]
    return torch.cat([rate, relative, root_h, root_v], dim=-1)


class SequenceJudgeNet(nn.Module):
    """Dilated 1-D convolutions over time, mean-pooled, to one score per style."""

    def __init__(self, channels: int, styles: int, width: int = 64) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv1d(channels, width, 5, padding=2), nn.ReLU(),
            nn.Conv1d(width, width, 5, padding=4, dilation=2), nn.ReLU(),
            nn.Conv1d(width, width, 5, padding=8, dilation=4), nn.ReLU(),
        )
        self.head = nn.Linear(width, styles)

    def forward(self, x: Tensor) -> Tensor:
        """``[B, T, C]`` standardised inputs -> ``[B, S]`` logits."""
        return self.head(self.body(x.transpose(1, 2)).mean(dim=2))


@dataclass
class SequenceJudge(JudgeFolder):
    """A trained sequence judge (network, input standardisation, rig and styles)."""

    kind: ClassVar[str] = KIND

    styles: list[str]
    skeleton: Skeleton
    fps: float
    net: SequenceJudgeNet
    mean: Tensor
    std: Tensor
    width: int = 64
    info: dict[str, Any] = field(default_factory=dict)

    def _inputs(self, positions: Tensor) -> Tensor:
        if positions.shape[-2] != len(self.skeleton.names):
            raise ValueError(f"the sequence judge is for {len(self.skeleton.names)} joints, got {positions.shape[-2]}")
        return (step_features(positions, self.skeleton, self.fps) - self.mean) / self.std

    @torch.no_grad()
    def log_probs(self, positions: Tensor) -> Tensor:
        """``[B, S]`` log-probabilities of each style for sequences of global positions ``[B, T, J, 3]``."""
        self.net.eval()
        x = self._inputs(positions)
        per = [torch.log_softmax(self.net(x[:, s:s + WINDOW - 1]), dim=-1) for s in window_starts(positions.shape[1])]
        return torch.stack(per).mean(dim=0).double()

    @torch.no_grad()
    def embed(self, positions: Tensor) -> Tensor:
        """``[B, width]`` the pooled features the judge's last layer reads (mean over windows)."""
        self.net.eval()
        x = self._inputs(positions)
        return torch.stack([self.net.body(x[:, s:s + WINDOW - 1].transpose(1, 2)).mean(2)
                            for s in window_starts(positions.shape[1])]).mean(0).double()

    def save(self, folder: str | Path) -> Path:
        meta = {"format": FORMAT, "kind": KIND, "styles": self.styles, "skeleton": self.skeleton.to_dict(),
                "fps": self.fps, "window": WINDOW, "width": self.width, "info": self.info}
        tensors = {f"net.{k}": v for k, v in self.net.state_dict().items()}
        return self.write_folder(folder, "sequence_judge.json", meta, {**tensors, "mean": self.mean, "std": self.std})

    @classmethod
    def load(cls, folder: str | Path) -> SequenceJudge:
        meta, t = cls.read_folder(folder, "sequence_judge.json", FORMAT, "sequence judge", "rsmt train sequence-judge")
        mean, std = t["mean"], t["std"]
        net = SequenceJudgeNet(mean.numel(), len(meta["styles"]), int(meta["width"]))
        net.load_state_dict({k[4:]: v for k, v in t.items() if k.startswith("net.")})
        return cls(styles=list(meta["styles"]), skeleton=Skeleton.from_dict(meta["skeleton"]), fps=float(meta["fps"]),
                   net=net, mean=mean, std=std, width=int(meta["width"]), info=dict(meta.get("info", {})))


@dataclass
class JudgeTraining:
    """How the sequence judge is trained."""

    steps: int = 1500
    batch: int = 256
    lr: float = 2e-3
    width: int = 64
    seed: int = 0
    weight_decay: float = 1e-4
    # Interpolated windows per step, as a share of ``batch``, and the weight of their uniform-answer term.
    interpolated_share: float = 0.25
    interpolated_weight: float = 0.5
    # The share of each step's real windows played backwards in time (labelled with their own style), in case a
    # style walks backwards as it walks forwards. Off: at 0.25 on both sets' val it read real windows 92.9% (93.8%
    # without), interpolated 15.6% (18.9%), the one backward val take 0% (6.1%): no help measured.
    reversed_share: float = 0.0

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch < 1 or self.width < 1:
            raise ValueError("steps, batch and width must be at least 1")
        if not 0.0 <= self.reversed_share <= 1.0:
            raise ValueError("reversed_share must be in [0, 1]")
        if not 0.0 <= self.interpolated_share <= 1.0 or self.interpolated_weight < 0:
            raise ValueError("interpolated_share must be in [0, 1] and interpolated_weight 0 or more")


def train_sequence_judge(windows: Tensor, labels: Tensor, styles: Sequence[str], skeleton: Skeleton, fps: float,
                         settings: JudgeTraining | None = None, contents: Sequence[str] | None = None,
                         interpolated: Tensor | None = None) -> SequenceJudge:
    """Fit a judge on real windows ``[N, WINDOW, J, 3]`` (global positions) with ``labels [N]`` into ``styles``.

    Every style is drawn equally often and, with ``contents`` (one per window), every content within a
    style too. ``interpolated [M, WINDOW, J, 3]``: windows whose in-betweens are interpolated, each step's
    ``interpolated_share`` of them scored against a uniform answer (module docstring).
    """
    settings = settings or JudgeTraining()
    if windows.shape[1] != WINDOW or (interpolated is not None and interpolated.shape[1] != WINDOW):
        raise ValueError(f"windows must have {WINDOW} poses, got {windows.shape[1]}")
    if contents is not None and len(contents) != len(windows):
        raise ValueError(f"one content per window: {len(contents)} for {len(windows)} windows")
    began = time.perf_counter()
    gen = torch.Generator().manual_seed(settings.seed)
    torch.manual_seed(settings.seed)
    x = _features(windows, skeleton, fps)
    flat = x.reshape(-1, x.shape[-1])
    mean, std = flat.mean(0), flat.std(0).clamp_min(1.0)  # cm/s: below 1 cm/s is not style
    x = (x - mean) / std
    xi = None if interpolated is None or not len(interpolated) else (_features(interpolated, skeleton, fps) - mean) / std
    xr = (_features(windows.flip(1), skeleton, fps) - mean) / std if settings.reversed_share > 0 else None
    n_interp = 0 if xi is None else round(settings.batch * settings.interpolated_share)
    net = SequenceJudgeNet(x.shape[-1], len(styles), settings.width)
    opt = torch.optim.AdamW(net.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=settings.lr, total_steps=settings.steps)
    groups = _groups(labels, contents)  # per style present: the rows of each of its contents
    net.train()
    loss_value = math.nan
    for _ in range(settings.steps):
        rows = _draw(groups, settings.batch, gen)
        # A little noise on the inputs, so the judge reads the motion rather than the capture's exact numbers.
        batch = x[rows]
        if xr is not None:
            back = torch.rand(len(rows), generator=gen) < settings.reversed_share
            batch = torch.where(back[:, None, None], xr[rows], batch)
        batch = batch + 0.05 * torch.randn((len(rows), *x.shape[1:]), generator=gen)
        loss = nn.functional.cross_entropy(net(batch), labels[rows])
        if xi is not None and n_interp > 0:
            pick = torch.randint(len(xi), (n_interp,), generator=gen)
            flat_answer = -torch.log_softmax(net(xi[pick]), dim=-1).mean()  # cross-entropy to a uniform answer
            loss = loss + settings.interpolated_weight * flat_answer
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        loss_value = float(loss.detach())
    info = {"train_windows": int(len(windows)), "interpolated_windows": 0 if xi is None else int(len(xi)),
            "balance": "style, then content" if contents is not None else "style",
            "interpolated_share": settings.interpolated_share if xi is not None else 0.0,
            "interpolated_weight": settings.interpolated_weight if xi is not None else 0.0,
            "reversed_share": settings.reversed_share,
            "steps": settings.steps, "batch": settings.batch,
            "final_loss": round(loss_value, 4), "train_seconds": round(time.perf_counter() - began, 1)}
    return SequenceJudge(list(styles), skeleton, float(fps), net, mean, std, settings.width, info)


def _features(windows: Tensor, skeleton: Skeleton, fps: float) -> Tensor:
    return torch.cat([step_features(windows[lo:lo + 1024], skeleton, fps) for lo in range(0, len(windows), 1024)])


def _groups(labels: Tensor, contents: Sequence[str] | None) -> list[list[Tensor]]:
    """For each style present in ``labels``, the row indices of each of its contents (one group without contents)."""
    out = []
    for k in labels.unique().tolist():
        rows = torch.nonzero(labels == k).squeeze(1)
        if contents is None:
            out.append([rows])
            continue
        names = sorted({contents[int(r)] for r in rows})
        out.append([rows[torch.tensor([contents[int(r)] == c for r in rows])] for c in names])
    return out


def _draw(groups: list[list[Tensor]], batch: int, gen: torch.Generator) -> Tensor:
    """``batch`` rows: a style uniformly, then one of its contents uniformly, then a window of it."""
    style = torch.randint(len(groups), (batch,), generator=gen).tolist()
    rows = []
    for s in style:
        g = groups[s]
        members = g[int(torch.randint(len(g), (1,), generator=gen))]
        rows.append(members[int(torch.randint(len(members), (1,), generator=gen))])
    return torch.stack(rows)

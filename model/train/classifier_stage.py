"""Training and checking the style classifier (:mod:`model.nets.style_classifier`) on cached takes.

Windows: ``window`` frames of motion (``window + 1`` poses, the first only for velocity) cut from
each take of a split with a fixed step, classifier input :func:`model.motion.features.local_frame_features`
computed once per take (a window's features are a slice of its take's, since every frame is
expressed in its own facing frame). Training windows optionally include left/right mirrored
takes (:mod:`model.motion.mirror`); batches draw every style equally often.

Checks (:func:`check_classifier`): accuracy on the real windows of a split per style and per
content, and the style accuracy given to the **interpolation** baseline between the first and last
pose of each window, i.e. a 40-frame interpolated transition between two poses of the right style.
A classifier that measures motion style should score the latter near chance (1 / styles); one
that scores it high is reading posture.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn
from tqdm import tqdm

from model.data.preprocessed import MotionCache
from model.evaluation.baselines import interpolate, zero_velocity
from model.motion.features import local_frame_features
from model.motion.kinematics import forward_kinematics
from model.motion.mirror import mirror_global, mirror_reflections
from model.motion.rotations import quat_normalize
from model.nets.style_classifier import StyleClassifier, StyleClassifierConfig, select_inputs

Tensor = torch.Tensor
log = logging.getLogger(__name__)


# ---------------------------------------------------------------------------------- windows
@dataclass
class WindowSet:
    """Per-take classifier features, concatenated, with the windows cut from them.

    Attributes:
        features: ``[N, J*12]`` rows of every take's ``local_frame_features`` (``frames - 1`` rows a take).
        starts: ``[W]`` first row of each window (``window`` rows long).
        style / content: ``[W]`` ids into ``styles`` / ``contents`` per window.
        take: ``[W]`` take index (into the cache) per window.
        mirrored: ``[W]`` whether the window comes from a mirrored copy.
    """

    features: Tensor
    starts: Tensor
    style: Tensor
    content: Tensor
    take: Tensor
    mirrored: Tensor
    window: int
    styles: list[str]
    contents: list[str]

    def __len__(self) -> int:
        return int(self.starts.numel())

    def gather(self, index: Tensor) -> Tensor:
        """``[B, window, J*12]`` features of windows ``index``."""
        rows = self.starts[index].unsqueeze(1) + torch.arange(self.window)
        return self.features[rows]


def _take_motion(cache: MotionCache, i: int) -> tuple[Tensor, Tensor]:
    clip = cache.clip(i)
    sk = clip.skeleton
    return forward_kinematics(quat_normalize(clip.rotations.float()), clip.root_positions.float(),
                              sk.offsets_tensor(), sk.parents)


def build_windows(
    cache: MotionCache,
    takes: Sequence[int],
    window: int = 40,
    step: int = 10,
    mirror: bool = False,
    styles: Sequence[str] | None = None,
    progress: bool = False,
    desc: str = "windows",
) -> WindowSet:
    """Windows of ``window`` motion frames every ``step`` frames from ``takes`` (and their mirrors).

    Takes whose style is not in ``styles`` (default: the cache's styles) are skipped.
    """
    styles = list(cache.styles if styles is None else styles)
    style_ids = {s: k for k, s in enumerate(styles)}
    contents = list(cache.contents)
    content_ids = {c: k for k, c in enumerate(contents)}
    reflections = None
    if mirror and takes:
        sample = list(takes)[:: max(1, len(takes) // 200)]
        reflections = mirror_reflections(cache.skeleton(takes[0]),
                                         torch.cat([cache.rotations(i)[::4] for i in sample]))
    parts, starts, sty, con, tk, mir = [], [], [], [], [], []
    row = 0
    for i in tqdm(list(takes), desc=desc, unit="take", disable=not progress, leave=False, file=sys.stderr):
        take = cache.takes[i]
        if take.style not in style_ids or cache.num_frames(i) < window + 1:
            continue
        pos, rot = _take_motion(cache, i)
        sk = cache.skeleton(i)
        copies = [(pos, rot, False)]
        if reflections is not None:
            mp, mr = mirror_global(pos.double(), rot.double(), sk, reflections)
            copies.append((mp.float(), mr.float(), True))
        for p, r, is_mirror in copies:
            feats = local_frame_features(p, r, sk)  # [T-1, C]
            n = feats.shape[0]
            for s in range(0, n - window + 1, step):
                starts.append(row + s)
                sty.append(style_ids[take.style])
                con.append(content_ids[take.content])
                tk.append(i)
                mir.append(is_mirror)
            parts.append(feats)
            row += n
    c = cache.skeleton(takes[0]).num_joints * 12 if takes else 0
    return WindowSet(
        features=torch.cat(parts) if parts else torch.zeros(0, c),
        starts=torch.tensor(starts, dtype=torch.long),
        style=torch.tensor(sty, dtype=torch.long),
        content=torch.tensor(con, dtype=torch.long),
        take=torch.tensor(tk, dtype=torch.long),
        mirrored=torch.tensor(mir, dtype=torch.bool),
        window=window, styles=styles, contents=contents,
    )


Baseline = Callable[[Tensor, Tensor, Tensor, Tensor, int], tuple[Tensor, Tensor]]


def baseline_windows(
    cache: MotionCache,
    takes: Sequence[int],
    window: int = 40,
    step: int = 20,
    method: Baseline = interpolate,
    styles: Sequence[str] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Classifier features of ``method`` transitions (default: interpolation) across each window.

    For every window of ``window + 1`` poses, the baseline generates poses ``1..window`` from pose
    ``0`` to pose ``window`` (the target); the features of pose 0 plus those frames are returned,
    i.e. exactly what the evaluation classifies for a 40-frame transition.

    Returns:
        ``(features [W, window, J*12], style ids [W], content ids [W])``.
    """
    styles = list(cache.styles if styles is None else styles)
    style_ids = {s: k for k, s in enumerate(styles)}
    content_ids = {c: k for k, c in enumerate(cache.contents)}
    feats, sty, con = [], [], []
    for i in takes:
        take = cache.takes[i]
        n = cache.num_frames(i)
        if take.style not in style_ids or n < window + 1:
            continue
        s = torch.arange(0, n - window, step)
        rot, root = quat_normalize(cache.rotations(i).float()), cache.root_positions(i).float()
        gen_rot, gen_root = method(rot[s], root[s], rot[s + window], root[s + window], window)
        all_rot = torch.cat([rot[s].unsqueeze(1), gen_rot], dim=1)
        all_root = torch.cat([root[s].unsqueeze(1), gen_root], dim=1)
        sk = cache.skeleton(i)
        p, r = forward_kinematics(all_rot, all_root, sk.offsets_tensor(), sk.parents)
        feats.append(local_frame_features(p, r, sk))
        sty += [style_ids[take.style]] * len(s)
        con += [content_ids[take.content]] * len(s)
    c = cache.skeleton(takes[0]).num_joints * 12 if takes else 0
    return (torch.cat(feats) if feats else torch.zeros(0, window, c),
            torch.tensor(sty, dtype=torch.long), torch.tensor(con, dtype=torch.long))


# ---------------------------------------------------------------------------------- training
@dataclass
class TrainSettings:
    """Optimisation settings of :func:`train_classifier`."""

    epochs: int = 12
    iterations: int = 150  # batches per epoch
    batch: int = 128
    lr: float = 2e-3
    lr_final: float = 2e-5
    weight_decay: float = 1e-3
    label_smoothing: float = 0.05
    step: int = 5  # frames between training windows
    eval_step: int = 20  # frames between validation / test windows
    mirror: bool = True
    seed: int = 0
    normalisation_windows: int = 4000


@dataclass
class TrainResult:
    model: StyleClassifier
    history: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = 0
    seconds: float = 0.0


def compute_normalisation(windows: WindowSet, inputs: str, count: int, seed: int = 0) -> tuple[Tensor, Tensor]:
    """Per-channel mean and std of the selected inputs over up to ``count`` windows (all their frames)."""
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(len(windows), generator=g)[:count]
    x = select_inputs(windows.gather(idx), inputs)
    x = x.reshape(-1, x.shape[-1]).double()
    return x.mean(0).float(), x.std(0, unbiased=False).float()


def accuracy(model: StyleClassifier, features: Tensor, labels: Tensor, batch: int = 512) -> float:
    if features.shape[0] == 0:
        return float("nan")
    logits, _ = model.predict(features, batch)
    return float((logits.argmax(-1) == labels).float().mean())


def _window_accuracy(model: StyleClassifier, windows: WindowSet, batch: int = 512) -> tuple[float, Tensor]:
    preds = []
    for i in range(0, len(windows), batch):
        idx = torch.arange(i, min(i + batch, len(windows)))
        logits, _ = model.predict(windows.gather(idx), batch)
        preds.append(logits.argmax(-1))
    if not preds:
        return float("nan"), torch.zeros(0, dtype=torch.long)
    pred = torch.cat(preds)
    return float((pred == windows.style).float().mean()), pred


def train_classifier(
    train: WindowSet,
    val: WindowSet | None,
    config: StyleClassifierConfig,
    settings: TrainSettings,
    progress: bool = True,
    report: Callable[[str], None] | None = None,
) -> TrainResult:
    """Train on ``train`` windows (style-balanced batches), keeping the epoch with the best validation accuracy."""
    if len(train) == 0:
        raise ValueError("no training windows: are the takes shorter than the window?")
    torch.manual_seed(settings.seed)
    model = StyleClassifier(config)
    mean, std = compute_normalisation(train, config.inputs, settings.normalisation_windows, settings.seed)
    model.set_normalisation(mean, std)
    opt = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    total = settings.epochs * settings.iterations

    def cosine(k: int) -> float:  # lr multiplier: lr at step 0, lr_final at the end
        lr = settings.lr_final + (settings.lr - settings.lr_final) * 0.5 * (1 + math.cos(math.pi * k / max(1, total)))
        return lr / settings.lr

    sched = torch.optim.lr_scheduler.LambdaLR(opt, cosine)
    loss_fn = nn.CrossEntropyLoss(label_smoothing=settings.label_smoothing)
    g = torch.Generator().manual_seed(settings.seed)
    by_style = [torch.nonzero(train.style == s).flatten() for s in range(len(config.styles))]
    present = [s for s, m in enumerate(by_style) if m.numel()]
    began = time.perf_counter()
    history: list[dict[str, float]] = []
    best: tuple[float, int, dict[str, Tensor] | None] = (-1.0, 0, None)
    bar = tqdm(total=total, desc="classifier", unit="batch", disable=not progress, file=sys.stderr, dynamic_ncols=True)
    with bar:
        for epoch in range(1, settings.epochs + 1):
            model.train()
            running, seen, correct = 0.0, 0, 0
            for _ in range(settings.iterations):
                pick = torch.tensor(present)[torch.randint(len(present), (settings.batch,), generator=g)]
                idx = torch.stack([by_style[s][torch.randint(by_style[s].numel(), (1,), generator=g)][0] for s in pick.tolist()])
                x = train.gather(idx)
                y = train.style[idx]
                logits = model(x)
                loss = loss_fn(logits, y)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(model.parameters(), 5.0)
                opt.step()
                sched.step()
                running += float(loss.detach()) * len(y)
                seen += len(y)
                correct += int((logits.argmax(-1) == y).sum())
                bar.update()
                bar.set_postfix(loss=f"{running / seen:.3f}")
            row = {"epoch": epoch, "loss": running / seen, "train_accuracy": correct / seen}
            if val is not None and len(val):
                row["val_accuracy"], _ = _window_accuracy(model, val)
            history.append(row)
            score = row.get("val_accuracy", row["train_accuracy"])
            if score > best[0]:
                best = (score, epoch, {k: v.clone() for k, v in model.state_dict().items()})
            line = (f"epoch {epoch}/{settings.epochs}: loss {row['loss']:.3f}, train acc {row['train_accuracy']:.3f}"
                    + (f", val acc {row['val_accuracy']:.3f}" if "val_accuracy" in row else ""))
            if report:
                report(line)
            log.info(line)
    if best[2] is not None:
        model.load_state_dict(best[2])
    model.eval()
    return TrainResult(model=model, history=history, best_epoch=best[1], seconds=time.perf_counter() - began)


# ---------------------------------------------------------------------------------- checks
def _per_group(pred: Tensor, truth: Tensor, groups: Tensor, names: Sequence[str]) -> dict[str, dict[str, float]]:
    out = {}
    for k, name in enumerate(names):
        m = groups == k
        if m.any():
            out[name] = {"accuracy": float((pred[m] == truth[m]).float().mean()), "windows": int(m.sum())}
    return out


def check_classifier(model: StyleClassifier, cache: MotionCache, takes: Sequence[int], step: int = 20) -> dict[str, Any]:
    """Accuracy on the real windows of ``takes`` (overall, per style, per content, confusion) and
    on interpolation and zero-velocity transitions across the same windows (module docstring)."""
    styles = model.styles
    window = model.config.window
    real = build_windows(cache, takes, window, step, mirror=False, styles=styles)
    acc, pred = _window_accuracy(model, real)
    confusion = torch.zeros(len(styles), len(styles), dtype=torch.long)
    for t, p in zip(real.style.tolist(), pred.tolist()):
        confusion[t, p] += 1
    result: dict[str, Any] = {
        "windows": len(real),
        "chance": 1.0 / len(styles),
        "accuracy": acc,
        "per_style": _per_group(pred, real.style, real.style, styles),
        "per_content": _per_group(pred, real.style, real.content, real.contents),
        "confusion": {"rows_true_cols_predicted": styles, "counts": confusion.tolist()},
    }
    for name, method in (("interpolation", interpolate), ("zero_velocity", zero_velocity)):
        feats, sty, _ = baseline_windows(cache, takes, window, step, method, styles)
        logits, _ = model.predict(feats)
        p = logits.argmax(-1)
        result[name] = {
            "accuracy": float((p == sty).float().mean()) if len(sty) else float("nan"),
            "per_style": _per_group(p, sty, sty, styles),
            "predicted_share": {s: float((p == k).float().mean()) for k, s in enumerate(styles)} if len(sty) else {},
        }
    return result


def format_check(check: dict[str, Any], title: str = "test") -> str:
    """A plain-text summary of :func:`check_classifier`'s result."""
    lines = [f"{title}: accuracy {check['accuracy']:.3f} on {check['windows']} real windows (chance {check['chance']:.3f})"]
    lines.append("  per style:   " + ", ".join(f"{k} {v['accuracy']:.3f}" for k, v in check["per_style"].items()))
    lines.append("  per content: " + ", ".join(f"{k} {v['accuracy']:.3f}" for k, v in check["per_content"].items()))
    for name in ("interpolation", "zero_velocity"):
        if name in check:
            lines.append(f"  {name} transitions scored as their style: {check[name]['accuracy']:.3f}")
    return "\n".join(lines)

"""The style judge: an independent style classifier for evaluation, unlike any training critic.

The training critics and ``rsmt train classifier`` (:mod:`model.nets.style_classifier`) are
temporal convolution nets on per-frame features (poses, velocities, accelerations). A model trained
against such a critic can learn to please that kind of net, so judging its style with another one
measures the agreement of two similar nets rather than style. The judge differs in both:

* **inputs**: a fixed vector of hand-made summary statistics of a whole window of global joint
  positions (:func:`window_features`), all unchanged by a turn about the vertical or a move on the
  ground: per joint, the mean, standard deviation and 90th percentile of its speed (cm/s) and of
  its speed relative to the root; the standard deviation of its vertical speed, of its height above
  the root (for the root: above the floor) and of its horizontal distance from the root; and the
  root's vertical bob: the standard deviation of its height and the power-weighted mean frequency
  of that signal (Hz). No acceleration and no per-frame vector is seen, and no mean posture: the
  key poses a transition starts and ends on carry their style's posture, so a judge reading
  postures would credit any transition between them (on the val split, 2026-11-25, posture
  statistics added 5 points on real windows and 40 on interpolated ones).
* **architecture**: multinomial logistic regression (a linear map of the standardised statistics
  to one score per style, softmax), fitted by L-BFGS with an L2 penalty. Each weight reads as
  "this statistic, in standard deviations, speaks for this style".

A window is :data:`WINDOW` poses (41: the last context frame and a 40-frame transition). A longer
sequence is scored as the mean log-probability of its 41-pose windows, 20 frames apart (the last
one ending on the last frame); a shorter one as one window.

Stored as ``judge.json`` (styles, joint names, feature names, training figures) and
``weights.safetensors`` (weight, bias and the standardisation), no pickle.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import torch
from tqdm import tqdm

from model.data.preprocessed import MotionCache
from model.motion.kinematics import forward_kinematics
from model.motion.rotations import quat_normalize

Tensor = torch.Tensor

FORMAT = "rsmt-style-judge/1"
WINDOW = 41
WINDOW_STEP = 20
STD_FLOOR = 0.01
KIND = ("multinomial logistic regression on window summary statistics (per joint: speed and speed relative to the "
        "root mean/std/p90, vertical speed std, height and horizontal reach from the root std; root bob std and "
        "frequency); no accelerations, no postures, no network")


def window_features(positions: Tensor, fps: float, root: int = 0) -> Tensor:
    """Summary statistics ``[B, 9 J + 2]`` of windows of global positions ``[B, T, J, 3]`` (cm, Y up, ``T >= 3``)."""
    if positions.dim() != 4 or positions.shape[-1] != 3 or positions.shape[1] < 3:
        raise ValueError(f"window_features needs positions [B, T>=3, J, 3], got {list(positions.shape)}")
    p = positions.to(torch.float64)
    velocity = (p[:, 1:] - p[:, :-1]) * fps  # [B, T-1, J, 3]
    speed = velocity.norm(dim=-1)
    relative = (velocity - velocity[:, :, root:root + 1]).norm(dim=-1)
    height = p[..., 1] - p[:, :, root:root + 1, 1]
    height[:, :, root] = p[:, :, root, 1]
    reach = (p[..., [0, 2]] - p[:, :, root:root + 1][..., [0, 2]]).norm(dim=-1)
    bob = p[:, :, root, 1] - p[:, :, root, 1].mean(dim=1, keepdim=True)  # [B, T]
    power = torch.fft.rfft(bob, dim=1).abs().square()[:, 1:]
    freqs = torch.fft.rfftfreq(p.shape[1], d=1.0 / fps, dtype=torch.float64)[1:]
    bob_freq = (power * freqs).sum(dim=1) / power.sum(dim=1).clamp_min(1e-9)
    parts = [speed.mean(1), speed.std(1), torch.quantile(speed, 0.9, dim=1), relative.mean(1), relative.std(1),
             torch.quantile(relative, 0.9, dim=1), velocity[..., 1].std(1), height.std(1), reach.std(1),
             bob.std(1, keepdim=True), bob_freq.unsqueeze(1)]
    return torch.cat(parts, dim=1)


class JudgeFolder:
    """What the style judges share: the most likely style, a description, and their folder (a JSON description
    beside weights.safetensors). A judge sets ``kind`` and has ``styles``, ``mean`` and ``info``."""

    kind: ClassVar[str]
    styles: list[str]
    mean: Tensor
    info: dict[str, Any]

    def log_probs(self, positions: Tensor) -> Tensor:
        raise NotImplementedError

    def predict(self, positions: Tensor) -> Tensor:
        """``[B]`` index into :attr:`styles` of the most likely style."""
        return self.log_probs(positions).argmax(dim=-1)

    def describe(self) -> dict[str, Any]:
        return {"kind": self.kind, "styles": self.styles, "window": WINDOW, "features": int(self.mean.numel()),
                **self.info}

    @staticmethod
    def write_folder(folder: str | Path, description: str, meta: dict[str, Any], tensors: dict[str, Tensor]) -> Path:
        """``meta`` as folder/``description`` and ``tensors`` as folder/weights.safetensors; the folder."""
        from safetensors.torch import save_file

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / description).write_text(json.dumps(meta, indent=1))
        save_file({k: v.contiguous() for k, v in tensors.items()}, str(folder / "weights.safetensors"))
        return folder

    @staticmethod
    def read_folder(folder: str | Path, description: str, form: str, what: str,
                    command: str) -> tuple[dict[str, Any], dict[str, Tensor]]:
        """The description (of format ``form``) and the tensors of a folder :meth:`write_folder` wrote; a folder
        without one is not a ``what`` folder (``command`` writes one)."""
        from safetensors.torch import load_file

        folder = Path(folder)
        path = folder / description
        if not path.is_file():
            raise FileNotFoundError(f"{folder} is not a {what} folder (no {description}; see {command})")
        meta = json.loads(path.read_text())
        if meta.get("format") != form:
            raise ValueError(f"{path}: format {meta.get('format')!r}, expected {form}")
        return meta, load_file(str(folder / "weights.safetensors"))


def feature_names(joints: Sequence[str]) -> list[str]:
    names = []
    for stat in ("speed mean", "speed std", "speed p90", "relative speed mean", "relative speed std",
                 "relative speed p90", "vertical speed std", "height std", "reach std"):
        names += [f"{j} {stat}" for j in joints]
    return [*names, "root bob std", "root bob frequency"]


def window_starts(length: int) -> list[int]:
    """Start frames of the :data:`WINDOW`-pose windows a sequence of ``length`` poses is scored on (both judges)."""
    if length <= WINDOW:
        return [0]
    starts = list(range(0, length - WINDOW + 1, WINDOW_STEP))
    if starts[-1] != length - WINDOW:
        starts.append(length - WINDOW)
    return starts


@dataclass
class StyleJudge(JudgeFolder):
    """A fitted judge: ``weight [S, F]``, ``bias [S]`` on features standardised by ``mean``/``std`` ``[F]``."""

    kind: ClassVar[str] = KIND

    styles: list[str]
    joints: list[str]
    fps: float
    root: int
    weight: Tensor
    bias: Tensor
    mean: Tensor
    std: Tensor
    info: dict[str, Any] = field(default_factory=dict)

    def standardise(self, features: Tensor) -> Tensor:
        """Window statistics ``[..., F]`` in standard deviations of the judge's training windows."""
        return (features.to(torch.float64) - self.mean) / self.std

    def logits_of_features(self, features: Tensor) -> Tensor:
        return self._logits(self.standardise(features))

    def _logits(self, z: Tensor) -> Tensor:
        return z @ self.weight.T + self.bias

    def _window_statistics(self, positions: Tensor) -> Tensor:
        """``[W, B, F]`` standardised statistics of the :data:`WINDOW`-pose windows of sequences ``[B, T, J, 3]``."""
        if positions.shape[-2] != len(self.joints):
            raise ValueError(f"the style judge is for {len(self.joints)} joints, got {positions.shape[-2]}")
        return torch.stack([self.standardise(window_features(positions[:, s:s + WINDOW], self.fps, self.root))
                            for s in window_starts(positions.shape[1])])

    def embed(self, positions: Tensor) -> Tensor:
        """``[B, F]`` standardised window statistics of sequences ``[B, T, J, 3]`` (the mean over their
        windows): what the judge reads, and the feature space of its FMD (:func:`judge_fmd_rows`)."""
        return self._window_statistics(positions).mean(dim=0)

    def log_probs(self, positions: Tensor) -> Tensor:
        """``[B, S]`` log-probabilities of each style for sequences of global positions ``[B, T, J, 3]``."""
        return torch.log_softmax(self._logits(self._window_statistics(positions)), dim=-1).mean(dim=0)

    def save(self, folder: str | Path) -> Path:
        meta = {"format": FORMAT, "kind": KIND, "styles": self.styles, "joints": self.joints, "fps": self.fps,
                "root": self.root, "window": WINDOW, "features": feature_names(self.joints), "info": self.info}
        return self.write_folder(folder, "judge.json", meta,
                                 {"weight": self.weight, "bias": self.bias, "mean": self.mean, "std": self.std})

    @classmethod
    def load(cls, folder: str | Path) -> StyleJudge:
        meta, t = cls.read_folder(folder, "judge.json", FORMAT, "style judge", "rsmt train judge")
        return cls(styles=list(meta["styles"]), joints=list(meta["joints"]), fps=float(meta["fps"]),
                   root=int(meta["root"]), weight=t["weight"].double(), bias=t["bias"].double(),
                   mean=t["mean"].double(), std=t["std"].double(), info=dict(meta.get("info", {})))


def fit_judge(features: Tensor, labels: Tensor, styles: Sequence[str], joints: Sequence[str], fps: float, root: int = 0,
              l2: float = 1e-3, iterations: int = 200) -> StyleJudge:
    """Multinomial logistic regression of ``labels [N]`` (indices into ``styles``) on ``features [N, F]``.

    Minimises the mean cross-entropy plus ``l2 / 2 * |W|^2`` with L-BFGS in float64, on features
    standardised by their training mean and std, the std at least :data:`STD_FLOOR` (0.01 cm, cm/s
    or Hz: smaller differences are round-off, not style).
    """
    x = features.to(torch.float64)
    mean = x.mean(dim=0)
    std = x.std(dim=0)
    std = std.clamp_min(STD_FLOOR)
    z = (x - mean) / std
    s = len(styles)
    weight = torch.zeros(s, z.shape[1], dtype=torch.float64, requires_grad=True)
    bias = torch.zeros(s, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([weight, bias], max_iter=iterations, line_search_fn="strong_wolfe", tolerance_grad=1e-9,
                            tolerance_change=1e-12, history_size=20)

    def closure() -> Tensor:
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(z @ weight.T + bias, labels) + 0.5 * l2 * weight.square().sum()
        loss.backward()
        return loss

    opt.step(closure)
    return StyleJudge(list(styles), list(joints), float(fps), int(root), weight.detach(), bias.detach(), mean, std,
                      info={"l2": l2, "train_windows": int(x.shape[0])})


def take_windows(cache: MotionCache, takes: Sequence[int], step: int = 10, progress: bool = False,
                 contents: Sequence[str] = ()) -> tuple[Tensor, list[str], list[str]]:
    """Features of every :data:`WINDOW`-pose window (``step`` frames apart) of ``takes``, optionally only
    those of ``contents``: ``(features [N, F], style per window, content per window)``."""
    feats: list[Tensor] = []
    styles: list[str] = []
    kinds: list[str] = []
    for i in tqdm(list(takes), desc="judge windows", unit="take", disable=not progress, leave=False, file=sys.stderr):
        take = cache.takes[i]
        if contents and take.content not in contents:
            continue
        n = cache.num_frames(i)
        starts = list(range(0, n - WINDOW + 1, step))
        if not starts:
            continue
        sk = cache.skeleton(i)
        pos, _ = forward_kinematics(quat_normalize(cache.rotations(i).float()), cache.root_positions(i).float(),
                                    sk.offsets_tensor(), sk.parents)
        w = torch.stack([pos[s:s + WINDOW] for s in starts])
        feats.append(window_features(w, cache.fps, sk.roles.root))
        styles += [take.style] * len(starts)
        kinds += [take.content] * len(starts)
    if not feats:
        raise ValueError(f"no take has the {WINDOW} frames of a judge window")
    return torch.cat(feats), styles, kinds


def accuracy_report(judge: StyleJudge, features: Tensor, styles: Sequence[str], contents: Sequence[str],
                    locomotion: Sequence[str]) -> dict[str, Any]:
    """Accuracy of ``judge`` on windows: overall, on locomotion contents, per style and per content."""
    index = {s: k for k, s in enumerate(judge.styles)}
    labels = torch.tensor([index.get(s, -1) for s in styles])
    hit = (judge.logits_of_features(features).argmax(-1) == labels).double()

    def acc(mask: Tensor) -> float | None:
        return float(hit[mask].mean()) if bool(mask.any()) else None

    content = list(contents)
    loco = torch.tensor([c in locomotion for c in content])
    return {"windows": len(styles), "accuracy": acc(labels >= 0), "locomotion_accuracy": acc(loco & (labels >= 0)),
            "chance": 1.0 / len(judge.styles),
            "per_style": {s: acc(labels == k) for s, k in index.items()},
            "per_content": {c: acc(torch.tensor([x == c for x in content])) for c in sorted(set(content))}}

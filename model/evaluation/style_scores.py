"""Style accuracy and FMD of transitions, from the style classifier (:mod:`model.nets.style_classifier`).

* ``style_accuracy``: the share of transitions the classifier assigns to the **requested** style
  (the style of the style clip the method was given). Baselines ignore the style clip, so for
  them the same-style figure only says what the classifier makes of their motion, and the
  cross-style figure should be low. Cases whose requested style the classifier does not know
  (a held-out style) are left out.
* ``fmd``: the Fréchet distance (:func:`model.evaluation.metrics.frechet_distance`) between the classifier's
  pooled features of the generated transitions and those of the ground-truth transitions of the
  same cases (RSMT's FMD, 40-frame gap, unchanged controls).
* ``fmd_cross``: for style clips of another style there is no ground truth; the reference set is
  built by giving each generated transition (requested style ``s``) the ground-truth transition of
  a case whose own style is ``s`` (round robin over those cases, deterministic), so both sets have
  the same style mix.

:func:`judge_rows`: the same accuracy from the style judge (:mod:`model.evaluation.style_judge`), a
classifier of another kind than any training critic, which gives the acceptance figures.

The classifier sees the last context frame followed by the generated frames (``N + 1`` poses give
``N`` frames of motion).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.evaluation.metrics import frechet_distance
from model.evaluation.scoring import Transitions
from model.evaluation.style_judge import StyleJudge
from model.motion.skeleton import Skeleton
from model.nets.style_classifier import StyleClassifier, motion_features

Tensor = torch.Tensor


class StyleScorer:
    def __init__(self, classifier: StyleClassifier, skeleton: Skeleton) -> None:
        if classifier.config.joints != skeleton.num_joints:
            raise ValueError(f"the style classifier is for {classifier.config.joints} joints, "
                             f"the data has {skeleton.num_joints}")
        self.classifier = classifier.eval()
        self.skeleton = skeleton
        self.index = {s: k for k, s in enumerate(classifier.styles)}

    def labels(self, styles: Sequence[str]) -> Tensor:
        """Class index per style name, -1 for a style the classifier does not know."""
        return torch.tensor([self.index.get(s, -1) for s in styles], dtype=torch.long)

    def classify(self, out: Transitions) -> tuple[Tensor, Tensor]:
        """``(logits [B, S], pooled features [B, D])``."""
        feats = motion_features(out.positions, out.rotations, self.skeleton)
        return self.classifier.predict(feats)

    @staticmethod
    def accuracy(logits: Tensor, labels: Tensor) -> float | None:
        known = labels >= 0
        if not known.any():
            return None
        return float((logits[known].argmax(-1) == labels[known]).float().mean())

    def accuracy_by_style(self, logits: Tensor, labels: Tensor, groups: Tensor | None = None) -> dict[str, float]:
        """Accuracy per requested style (the classifier's styles that occur in ``labels``), or, given
        ``groups`` (class indices, e.g. the context's style), per group, each case scored on its label."""
        groups = labels if groups is None else groups
        hit = logits.argmax(-1) == labels
        return {name: float(hit[(groups == i) & (labels >= 0)].float().mean())
                for name, i in self.index.items() if bool(((groups == i) & (labels >= 0)).any())}

    @staticmethod
    def fmd(features: Tensor, reference: Tensor) -> float | None:
        if features.shape[0] < 2 or reference.shape[0] < 2:
            return None
        return float(frechet_distance(features, reference))


def matched_reference(gt_features: Tensor, case_styles: Sequence[str], requested: Sequence[str]) -> tuple[Tensor, Tensor]:
    """For each requested style, the ground-truth feature of the next case of that style (round robin).

    Returns ``(reference features [M, D], index [M] of the requests that got one)``; requests of a
    style no case has are dropped.
    """
    pools: dict[str, list[int]] = {}
    for i, s in enumerate(case_styles):
        pools.setdefault(s, []).append(i)
    turn: dict[str, int] = {}
    rows, kept = [], []
    for k, s in enumerate(requested):
        pool = pools.get(s)
        if not pool:
            continue
        j = turn.get(s, 0)
        rows.append(pool[j % len(pool)])
        turn[s] = j + 1
        kept.append(k)
    idx = torch.tensor(rows, dtype=torch.long)
    return gt_features[idx] if rows else gt_features[:0], torch.tensor(kept, dtype=torch.long)


def judge_rows(judge: StyleJudge, positions: Tensor, requested: Sequence[str], prefix: str = "judge_accuracy") -> dict:
    """The style judge's accuracy on sequences ``[B, T, J, 3]`` against the requested styles, overall
    (``prefix``) and per requested style (``prefix + "_by_style"``); styles it does not know are left out."""
    index = {s: k for k, s in enumerate(judge.styles)}
    labels = torch.tensor([index.get(s, -1) for s in requested], dtype=torch.long)
    known = labels >= 0
    if not bool(known.any()):
        return {}
    hit = judge.predict(positions) == labels
    return {prefix: float(hit[known].float().mean()),
            prefix + "_by_style": {s: float(hit[labels == k].float().mean()) for s, k in index.items()
                                   if bool((labels == k).any())}}

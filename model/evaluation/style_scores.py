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
classifier of another kind than any training critic, which gives the acceptance figures, with the
mean probability it gives the requested style; :func:`judge_fmd_rows`: FMD in the judge's feature
space (summary statistics no training network sees), with its noise floor :func:`judge_fmd_floor`.

The classifier sees the last context frame followed by the generated frames (``N + 1`` poses give
``N`` frames of motion).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from model.evaluation.metrics import frechet_distance
from model.evaluation.scoring import Transitions
from model.evaluation.sequence_judge import SequenceJudge
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


def judge_rows(judge: StyleJudge | SequenceJudge, positions: Tensor, requested: Sequence[str],
               prefix: str = "judge_accuracy") -> dict:
    """The style judge's accuracy on sequences ``[B, T, J, 3]`` against the requested styles, overall
    (``prefix``) and per requested style (``prefix + "_by_style"``), the mean probability it gives the
    requested style (``..._prob``, ``..._prob_by_style``) and the share of each requested style's cases it
    reads as each style (``..._read_as_by_style``); styles it does not know are left out."""
    index = {s: k for k, s in enumerate(judge.styles)}
    labels = torch.tensor([index.get(s, -1) for s in requested], dtype=torch.long)
    known = labels >= 0
    if not bool(known.any()):
        return {}
    log_probs = judge.log_probs(positions)
    hit = log_probs.argmax(dim=-1) == labels
    # The probability the judge gives the requested style: it moves before the accuracy does, which shows a
    # style clip pulling the motion toward its style even where the judge's vote still goes elsewhere.
    prob = log_probs.exp().gather(1, labels.clamp_min(0).unsqueeze(1)).squeeze(1)
    present = {s: k for s, k in index.items() if bool((labels == k).any())}
    # What each requested style is read as (a row of the confusion matrix): where a style is missed, the
    # style the motion fell back to says what the model did with the clip.
    votes = log_probs.argmax(dim=-1)
    read_as = {s: {t: float((votes[labels == k] == j).float().mean()) for t, j in index.items()}
               for s, k in present.items()}
    return {prefix: float(hit[known].float().mean()),
            prefix + "_by_style": {s: float(hit[labels == k].float().mean()) for s, k in present.items()},
            prefix + "_prob": float(prob[known].mean()),
            prefix + "_prob_by_style": {s: float(prob[labels == k].mean()) for s, k in present.items()},
            prefix + "_read_as_by_style": read_as}


def judge_fmd_rows(judge: StyleJudge, positions: Tensor, reference: Tensor, styles: Sequence[str]) -> dict:
    """FMD in the judge's feature space: the Fréchet distance between the judge's standardised window
    statistics (:meth:`StyleJudge.embed`) of transitions ``[B, T, J, 3]`` and of the real transitions of the
    same cases (``reference``, same shape), over all cases (``judge_fmd``) and per case style
    (``judge_fmd_by_style``; styles with fewer than two cases are left out). No training network shares
    these features, unlike the classifier's FMD (:class:`StyleScorer`)."""
    if positions.shape != reference.shape or positions.shape[0] != len(styles):
        raise ValueError(f"judge FMD needs transitions and references of one shape, a style per case; got "
                         f"{list(positions.shape)}, {list(reference.shape)} and {len(styles)} styles")
    feats, ref = judge.embed(positions), judge.embed(reference)
    return {"judge_fmd": StyleScorer.fmd(feats, ref),
            "judge_fmd_by_style": {s: StyleScorer.fmd(feats[i], ref[i]) for s, i in _cases_by_style(styles, 2).items()}}


def judge_fmd_floor(judge: StyleJudge, reference: Tensor, styles: Sequence[str]) -> dict:
    """The noise floor of :func:`judge_fmd_rows` at this number of cases: real transitions of alternate
    cases against each other, over all cases and per style (``judge_fmd_split_half``, ``..._by_style``)."""
    feats = judge.embed(reference)
    return {"judge_fmd_split_half": StyleScorer.fmd(feats[0::2], feats[1::2]),
            "judge_fmd_split_half_by_style": {s: StyleScorer.fmd(feats[i[0::2]], feats[i[1::2]])
                                              for s, i in _cases_by_style(styles, 4).items()}}


def _cases_by_style(styles: Sequence[str], at_least: int) -> dict[str, Tensor]:
    """The case indices of each style with at least ``at_least`` cases, styles in name order."""
    return {s: idx for s in sorted(set(styles))
            if len(idx := torch.tensor([i for i, c in enumerate(styles) if c == s])) >= at_least}

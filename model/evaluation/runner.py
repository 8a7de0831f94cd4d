"""Run methods on the evaluation cases of a split and collect every score into one report (a JSON-ready dict).

Order of work: reference statistics from the training split; the cases of the chosen split
(:mod:`model.evaluation.cases`); then for each method and each variant, the deterministic
transitions (noise off) with the same-style clip, scored (:mod:`model.evaluation.scoring`); on
the 40-frame gap also the cross-style clip, and with a classifier the style accuracy and FMD
(:mod:`model.evaluation.style_scores`); for methods that can sample, diversity on a bounded,
evenly spread subset of the cases (``diversity_samples`` transitions each, noise on).

Every variant is scored twice: on all cases (``variants``) and on the locomotion cases alone
(``locomotion``: walk, walk turns, run; the acceptance figures). The turned and moved targets are
asked of the locomotion cases only. With a style judge (:mod:`model.evaluation.style_judge`), every
transition of at least 40 frames also gets the judge's style accuracy and the mean probability it gives
the requested style, overall and per style, and the 40-frame gap the judge's FMD to the real transitions.
Methods are sent ``settings.target_frames`` target frames (1: the target alone, the default).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from tqdm import tqdm

from model.data.preprocessed import MotionCache
from model.data.splits import Split
from model.evaluation import metrics
from model.evaluation.cases import (
    CONTEXT,
    GAP_VARIANTS,
    VARIANTS,
    CaseSet,
    Variant,
    build_cases,
    stable_hash,
)
from model.evaluation.floor import floor_depth
from model.evaluation.methods import BaselineMethod, Method, Request, Unavailable
from model.evaluation.reference import ReferenceStats, reference_stats
from model.evaluation.run_description import (
    describe_cases,
    describe_protocol,
    describe_reference,
    describe_scorers,
    describe_variants,
)
from model.evaluation.scoring import (
    Transitions,
    gait_rows,
    ground_truth_transitions,
    root_speed,
    score,
    to_canonical,
)
from model.evaluation.sequence_judge import SequenceJudge
from model.evaluation.style_judge import StyleJudge
from model.evaluation.style_scores import StyleScorer, judge_fmd_floor, judge_fmd_rows, judge_rows, matched_reference
from model.nets.style_classifier import StyleClassifier

Tensor = torch.Tensor
log = logging.getLogger(__name__)

FORMAT = "rsmt-eval/2"
STYLE_GAP = 40
GT_NAME = "ground truth"


@dataclass
class EvalSettings:
    """What to evaluate: the split, a case limit, the seed of the noisy samples and the diversity subset."""

    split: str = "test"
    limit: int | None = None
    seed: int = 0
    diversity_cases: int = 32
    diversity_samples: int = 10
    render_cases: int = 4
    styles: tuple[str, ...] = ()  # only cases of these styles (e.g. a held-out one); all when empty
    target_frames: int = 1  # target frames sent to bundles: 1 (the target alone) or 2 (with its velocity)
    # Bundles sample their per-transition noise, one seed per case and variant from ``seed``, as a request
    # with the API's default ``"deterministic": false`` does; False: no noise (the figures so far).
    noise: bool = False
    # Styles put aside from the split (its ``holdout`` split, ``split="holdout"``); the training split of motion
    # matching and the reference statistics is then the one a model trained with the same held-out styles saw.
    holdout_styles: tuple[str, ...] = ()
    clips_only: tuple[str, ...] = ()  # take ids that give no case but serve as style clips (fine-tuning clips)
    # Sets of take ids, each of one style: that style's cases are asked with the set's clips encoded together (a
    # registration of several clips) instead of one clip; cross-style requests keep their one clip.
    style_sets: tuple[tuple[str, ...], ...] = ()


@dataclass
class EvalRun:
    """The report plus what the renderer needs: canonical positions of a few cases per method."""

    report: dict[str, Any]
    cases: CaseSet
    stats: ReferenceStats
    loco: CaseSet | None = None  # the locomotion cases (None when there are none)
    judge: StyleJudge | None = None
    judge2: SequenceJudge | None = None  # the second judge (another family), reported beside the first
    render_index: list[int] = field(default_factory=list)
    render: dict[str, dict[str, Tensor]] = field(default_factory=dict)  # method -> variant -> [R, N+1, J, 3]


def _spread(n: int, k: int) -> list[int]:
    if k <= 0:
        return []
    if k >= n:
        return list(range(n))
    return [(i * n) // k for i in range(k)]


def _render_cases(cases: CaseSet, k: int) -> list[int]:
    """Up to ``k`` cases with different (style, content), evenly spread."""
    seen, picked = set(), []
    for i in _spread(len(cases), max(k * 8, k)):
        key = (cases.cases[i].style, cases.cases[i].content)
        if key not in seen:
            seen.add(key)
            picked.append(i)
    return sorted(picked[:: max(1, len(picked) // k)][:k]) if picked else []


def eval_split(cache: MotionCache, settings: EvalSettings) -> Split:
    """The split ``settings`` evaluates on: the cache's default one, or one with ``settings.holdout_styles`` aside."""
    if settings.split == "holdout" and not settings.holdout_styles:
        raise ValueError("the holdout split needs the held-out styles (--holdout-style)")
    return cache.make_split(holdout_styles=settings.holdout_styles) if settings.holdout_styles else cache.split


def style_set_takes(cache: MotionCache, sets: Sequence[Sequence[str]]) -> dict[str, list[int]]:
    """Each style set (take ids) as its style and take indices; a ValueError for an unknown take, a set mixing
    styles, two sets of one style or a set of more than five clips."""
    out: dict[str, list[int]] = {}
    for names in sets:
        indices = cache.indices_of(names, "style sets")
        styles = sorted({cache.takes[i].style for i in indices})
        if len(styles) != 1:
            raise ValueError(f"a style set holds clips of one style; {', '.join(names)} are {', '.join(styles)}")
        if styles[0] in out:
            raise ValueError(f"two style sets of {styles[0]}")
        if not 1 <= len(names) <= 5:
            raise ValueError(f"a style set holds 1 to 5 clips, not {len(names)}")
        out[styles[0]] = indices
    return out


def evaluate(
    cache: MotionCache,
    methods: list[Method],
    settings: EvalSettings,
    classifier: StyleClassifier | None = None,
    classifier_path: str | None = None,
    progress: bool = True,
    stats: ReferenceStats | None = None,
    judge: StyleJudge | None = None,
    judge_path: str | None = None,
    judge2: SequenceJudge | None = None,
    judge2_path: str | None = None,
) -> EvalRun:
    """Evaluate ``methods`` on the cases of ``settings.split`` of ``cache``; see the module docstring."""
    began = time.perf_counter()
    split = eval_split(cache, settings)
    takes = split[settings.split]
    cache.indices_of(settings.clips_only, "clips-only takes")  # a ValueError for an unknown one
    if stats is None:
        stats = reference_stats(cache, split.train, progress=progress)
    cases = _load_cases(cache, settings, takes, split)
    scorer = StyleScorer(classifier, cases.skeleton) if classifier is not None else None
    render_index = _render_cases(cases, settings.render_cases)
    if settings.target_frames not in (1, 2):
        raise ValueError(f"target frames must be 1 or 2, not {settings.target_frames}")
    loco = cases.subset(cases.locomotion_index) if cases.locomotion_index else None
    run = EvalRun(report={}, cases=cases, render_index=render_index, stats=stats, loco=loco, judge=judge,
                  judge2=judge2)

    gt_rows, gt_features = _score_ground_truth(run, scorer)
    method_reports = _score_methods(run, methods, settings, scorer, gt_features, progress)
    if render_index and not any(isinstance(m, BaselineMethod) and m.name == "interp" for m in methods):
        _render_interpolation(run)

    run.report = {
        "format": FORMAT,
        **describe_cases(cache, asdict(settings), cases),
        "protocol": describe_protocol(settings.target_frames, settings.noise),
        "variants": describe_variants(),
        "reference": describe_reference(stats, cases),
        **describe_scorers(classifier, classifier_path, judge, judge_path, judge2, judge2_path),
        "ground_truth": gt_rows,
        "ground_truth_locomotion": _score_ground_truth_locomotion(run),
        "methods": method_reports,
        "seconds": round(time.perf_counter() - began, 2),
    }
    return run


def _load_cases(cache: MotionCache, settings: EvalSettings, takes: Sequence[int], split: Split) -> CaseSet:
    """The cases of ``takes`` (of the styles asked for, when any), loaded with their style clips."""
    unknown = sorted(set(settings.styles) - set(cache.styles))
    if unknown:
        raise ValueError(f"unknown style(s) {', '.join(unknown)}: the data has {', '.join(cache.styles)}")
    case_list = build_cases(cache, takes, settings.limit, only_styles=settings.styles,
                            clip_fallback=split.train if settings.split != "train" else (),
                            clips_only=settings.clips_only)
    return CaseSet.load(cache, case_list, style_set_takes(cache, settings.style_sets))


def _score_methods(run: EvalRun, methods: list[Method], settings: EvalSettings, scorer: StyleScorer | None,
                   gt_features: Tensor | None, progress: bool) -> dict[str, Any]:
    """Each method's report by its name (primed where two methods share one, or one is the ground truth's)."""
    method_reports: dict[str, Any] = {}
    names: list[str] = []
    for method in methods:
        name = method.name
        while name in names or name == GT_NAME:
            name += "'"
        names.append(name)
        t0 = time.perf_counter()
        rows = _score_method(run, method, name, settings, scorer, gt_features, progress)
        loco_rows = rows.pop("locomotion")
        method_reports[name] = {**method.describe(), "name": name, "seconds": round(time.perf_counter() - t0, 2),
                                "locomotion": loco_rows, "variants": rows}
    return method_reports


def _render_interpolation(run: EvalRun) -> None:
    """Interpolation's transitions of the rendered cases: the contact sheet always shows interpolation beside
    the model and the ground truth."""
    interp, sub = BaselineMethod("interp"), run.cases.subset(run.render_index)
    run.render["interp"] = {v.name: to_canonical(sub, *interp.generate(sub, Request(v))).positions
                            for v in VARIANTS if not v.locomotion_only}


def _score_ground_truth(run: EvalRun, scorer: StyleScorer | None) -> tuple[dict[str, dict[str, Any]], Tensor | None]:
    """Ground truth's rows (foot skate, what the classifier makes of real transitions) and its
    classifier features at the style gap, which the methods' FMD compares against."""
    cases, stats = run.cases, run.stats
    styles = [c.style for c in cases.cases]
    gt_rows: dict[str, dict[str, Any]] = {}
    gt_features: Tensor | None = None
    run.render[GT_NAME] = {}
    for v in GAP_VARIANTS:
        gt = ground_truth_transitions(cases, v)
        row: dict[str, Any] = {"cases": len(cases), "frames": v.gap,
                               "foot_skate": float(metrics.foot_skate(gt.positions, stats.feet, stats.ground)),
                               "floor_depth_cm": float(floor_depth(gt.generated_positions, stats.feet, stats.ground).mean()),
                               **root_speed(gt.positions, cases), **gait_rows(gt.positions, cases)}
        if run.judge is not None and v.gap == STYLE_GAP:
            row.update(judge_rows(run.judge, gt.positions, styles))
            row.update(judge_fmd_floor(run.judge, gt.positions, styles))
        if run.judge2 is not None and v.gap == STYLE_GAP:
            row.update(judge_rows(run.judge2, gt.positions, styles, prefix="judge2_accuracy"))
        if scorer is not None and v.gap == STYLE_GAP:
            logits, gt_features = scorer.classify(gt)
            row["style_accuracy"] = scorer.accuracy(logits, scorer.labels(styles))
            row["style_accuracy_by_style"] = scorer.accuracy_by_style(logits, scorer.labels(styles))
            # The noise floor of FMD at this many cases: ground truth against ground truth of other cases.
            row["fmd_split_half"] = scorer.fmd(gt_features[0::2], gt_features[1::2])
        gt_rows[v.name] = row
        run.render[GT_NAME][v.name] = gt.positions[run.render_index]
    return gt_rows, gt_features


def _score_ground_truth_locomotion(run: EvalRun) -> dict[str, dict[str, Any]]:
    """Ground truth's rows on the locomotion cases: foot skate, largest root speed (also the context's, for
    scale) and the judge's accuracy on real 40-frame transitions."""
    loco = run.loco
    if loco is None:
        return {}
    rows: dict[str, dict[str, Any]] = {}
    styles = [c.style for c in loco.cases]
    for v in GAP_VARIANTS:
        gt = ground_truth_transitions(loco, v)
        row: dict[str, Any] = {"cases": len(loco), "frames": v.gap,
                               "foot_skate": float(metrics.foot_skate(gt.positions, run.stats.feet, run.stats.ground)),
                               "floor_depth_cm": float(floor_depth(gt.generated_positions, run.stats.feet,
                                                                   run.stats.ground).mean()),
                               **root_speed(gt.positions, loco), **gait_rows(gt.positions, loco)}
        context = root_speed(loco.canonical_positions[:, :CONTEXT], loco)
        row.update({f"context_{k}": x for k, x in context.items()})
        if run.judge is not None and v.gap == STYLE_GAP:
            row.update(judge_rows(run.judge, gt.positions, styles))
            row.update(judge_fmd_floor(run.judge, gt.positions, styles))
        if run.judge2 is not None and v.gap == STYLE_GAP:
            row.update(judge_rows(run.judge2, gt.positions, styles, prefix="judge2_accuracy"))
        rows[v.name] = row
    return rows


def _score_method(run: EvalRun, method: Method, name: str, settings: EvalSettings, scorer: StyleScorer | None,
                  gt_features: Tensor | None, progress: bool) -> dict[str, Any]:
    """One method's rows, one per variant, on all cases (returned) and on the locomotion cases
    (``rows["locomotion"]``, a dict by variant like the rest)."""
    rows: dict[str, Any] = {}
    loco_rows: dict[str, Any] = {}
    run.render[name] = {}
    for v in tqdm(VARIANTS, desc=name, unit="variant", disable=not progress, leave=False, file=sys.stderr):
        on = run.loco if v.locomotion_only else run.cases
        if on is None:
            loco_rows[v.name] = {"unavailable": "no locomotion case"}
            continue
        try:
            rot, root = method.generate(on, _request(v, on, settings), progress)
        except Unavailable as exc:
            loco_rows[v.name] = {"unavailable": str(exc)}
            if not v.locomotion_only:
                rows[v.name] = {"unavailable": str(exc)}
            continue
        out = to_canonical(on, rot, root)
        if v.locomotion_only:
            loco_rows[v.name] = _judged(run, v, on, out)
            continue
        rows[v.name], cross = _variant_row(run, method, name, v, out, settings, scorer, gt_features, progress)
        if run.loco is not None:
            loco_rows[v.name] = _locomotion_row(run, run.loco, v, out, cross)
    rows["locomotion"] = loco_rows
    return rows


def _variant_row(run: EvalRun, method: Method, name: str, v: Variant, out: Transitions, settings: EvalSettings,
                 scorer: StyleScorer | None, gt_features: Tensor | None,
                 progress: bool) -> tuple[dict[str, Any], Transitions | None]:
    """A method's row of variant ``v`` on all cases (scores, style, diversity, the judges on other-style clips),
    and its transitions with the other-style clips where any scorer reads them (else None)."""
    cases = run.cases
    row: dict[str, Any] = _judged(run, v, cases, out)
    run.render[name][v.name] = out.positions[run.render_index]
    cross = None
    if v.gap == STYLE_GAP and v.has_ground_truth and (scorer is not None or run.judge is not None
                                                      or run.judge2 is not None):
        cross = _cross_style(run, method, v, out, settings, progress)
    if scorer is not None and v.gap == STYLE_GAP:
        row.update(_style_row(run, v, out, cross, scorer, gt_features))
    if (method.stochastic and v.has_ground_truth and settings.diversity_samples >= 2
            and settings.diversity_cases > 0):
        row.update(_diversity(method, cases, v, settings, progress))
    if cross is not None:
        row.update(_judges_cross(run, cases, cross.positions))
    return row, cross


def _locomotion_row(run: EvalRun, loco: CaseSet, v: Variant, out: Transitions,
                    cross: Transitions | None) -> dict[str, Any]:
    """The row of variant ``v`` on the locomotion cases, cut from the transitions of all cases."""
    idx = run.cases.locomotion_index
    row = _judged(run, v, loco, Transitions(out.positions[idx], out.rotations[idx]))
    if cross is not None:
        row.update(_judges_cross(run, loco, cross.positions[idx]))
    return row


def _judged(run: EvalRun, v: Variant, cases: CaseSet, out: Transitions) -> dict[str, Any]:
    """:func:`score` of ``out`` plus, for 40 frames or more and a judge, the judge's style accuracy; on the
    40-frame gap with ground truth also the judge's FMD to the real transitions."""
    row: dict[str, Any] = score(cases, v, out, run.stats)
    styles = [c.style for c in cases.cases]
    if run.judge is not None and v.frames >= STYLE_GAP:
        row.update(judge_rows(run.judge, out.positions, styles))
    if run.judge2 is not None and v.frames >= STYLE_GAP:
        row.update(judge_rows(run.judge2, out.positions, styles, prefix="judge2_accuracy"))
    if run.judge is not None and v.gap == STYLE_GAP and v.has_ground_truth:
        row.update(judge_fmd_rows(run.judge, out.positions, ground_truth_transitions(cases, v).positions, styles))
    return row


def _cross_style(run: EvalRun, method: Method, v: Variant, out: Transitions, settings: EvalSettings,
                 progress: bool) -> Transitions:
    """The method's transitions with each case's other-style clip (``out`` itself where the style clip is ignored)."""
    if not method.uses_style:
        return out
    rot, root = method.generate(run.cases, _request(v, run.cases, settings, cross_style=True), progress)
    return to_canonical(run.cases, rot, root)


def _request(v: Variant, cases: CaseSet, settings: EvalSettings, cross_style: bool = False) -> Request:
    """What every case of ``cases`` is asked on variant ``v``: with a noise seed per case when ``settings.noise``."""
    seeds = ([stable_hash(settings.seed, c.id, v.name, "noise", cross_style) % (2**31) for c in cases.cases]
             if settings.noise else None)
    return Request(v, cross_style=cross_style, seeds=seeds, target_frames=settings.target_frames)


def _judges_cross(run: EvalRun, cases: CaseSet, positions: Tensor) -> dict[str, Any]:
    """:func:`_judge_cross` of each judge given (the second's figures prefixed ``judge2``)."""
    row: dict[str, Any] = {}
    if run.judge is not None:
        row.update(_judge_cross(run.judge, cases, positions))
    if run.judge2 is not None:
        row.update(_judge_cross(run.judge2, cases, positions, "judge2"))
    return row


def _judge_cross(judge: StyleJudge | SequenceJudge, cases: CaseSet, positions: Tensor,
                 name: str = "judge") -> dict[str, Any]:
    """The judge's accuracy with other-style clips, on the clip's style, and the share read as the context's style."""
    row = judge_rows(judge, positions, [c.cross_style for c in cases.cases], prefix=f"{name}_accuracy_cross")
    as_context = judge_rows(judge, positions, [c.style for c in cases.cases], prefix=f"{name}_cross_as_context")
    return {**row, **as_context}


def _style_row(run: EvalRun, v: Variant, out: Transitions, cross: Transitions | None, scorer: StyleScorer,
               gt_features: Tensor | None) -> dict[str, Any]:
    """Style accuracy of a method's transitions; with ground truth also FMD and the other-style clip figures."""
    cases = run.cases
    styles = [c.style for c in cases.cases]
    cross_styles = [c.cross_style for c in cases.cases]
    logits, feats = scorer.classify(out)
    row: dict[str, Any] = {"style_accuracy": scorer.accuracy(logits, scorer.labels(styles)),
                           "style_accuracy_by_style": scorer.accuracy_by_style(logits, scorer.labels(styles))}
    if not v.has_ground_truth:
        return row
    assert gt_features is not None
    row["fmd"] = scorer.fmd(feats, gt_features)
    assert cross is not None
    logits_x, feats_x = (logits, feats) if cross is out else scorer.classify(cross)
    row["style_accuracy_cross"] = scorer.accuracy(logits_x, scorer.labels(cross_styles))
    # Where the misses go: the share read as the context's own style (the clip ignored).
    row["style_cross_as_context"] = scorer.accuracy(logits_x, scorer.labels(styles))
    row["style_accuracy_cross_by_style"] = scorer.accuracy_by_style(logits_x, scorer.labels(cross_styles))
    # And by the context's style: which contexts make another style's clip hard to follow.
    row["style_accuracy_cross_by_context"] = scorer.accuracy_by_style(
        logits_x, scorer.labels(cross_styles), groups=scorer.labels(styles))
    ref, kept = matched_reference(gt_features, styles, cross_styles)
    row["fmd_cross"] = scorer.fmd(feats_x[kept], ref)
    return row


def _diversity(method: Method, cases: CaseSet, v: Variant, settings: EvalSettings, progress: bool) -> dict[str, Any]:
    """Mean pairwise distance (cm) between ``diversity_samples`` noisy transitions per case, on a case subset."""
    index = _spread(len(cases), settings.diversity_cases)
    sub = cases.subset(index)
    samples = []
    for k in range(settings.diversity_samples):
        seeds = [stable_hash(settings.seed, c.id, v.name, k) % (2**31) for c in sub.cases]
        try:
            rot, root = method.generate(sub, Request(v, seeds=seeds, target_frames=settings.target_frames), progress)
        except Unavailable:
            return {}
        samples.append(to_canonical(sub, rot, root).generated_positions)
    return {"diversity_cm": float(metrics.diversity(torch.stack(samples))), "diversity_cases": len(sub),
            "diversity_samples": settings.diversity_samples}

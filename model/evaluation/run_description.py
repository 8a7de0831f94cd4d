"""What an evaluation report says about how its figures were made: the cases, the protocol, the variants,
the reference statistics and the style scorers (the parts of the report that are not scores)."""

from __future__ import annotations

from typing import Any

from model.data.preprocessed import MotionCache
from model.evaluation.cases import CASE_STEP, CONTEXT, LOCOMOTION, SPAN, STYLE_CLIP_FRAMES, VARIANTS, CaseSet
from model.evaluation.reference import ReferenceStats
from model.evaluation.sequence_judge import SequenceJudge
from model.evaluation.style_judge import StyleJudge
from model.nets.style_classifier import StyleClassifier


def describe_cases(cache: MotionCache, settings: dict[str, Any], cases: CaseSet) -> dict[str, Any]:
    """The data, the split, the settings (the evaluation's, as a dict) and the cases evaluated on."""
    return {
        "data": str(cache.data_root),
        "cache": cache.key,
        "split": settings["split"],
        "settings": settings,
        "cases": len(cases),
        "locomotion_cases": len(cases.locomotion_index),
        "locomotion_contents": list(LOCOMOTION),
        "target_frames": settings["target_frames"],
        "takes": len({c.take for c in cases.cases}),
        "case_ids": [c.id for c in cases.cases],
        "styles": sorted({c.style for c in cases.cases}),
    }


def describe_protocol(target_frames: int, noise: bool) -> dict[str, Any]:
    """The case windows, the target sent (``target_frames`` frames), the noise and how style clips are paired."""
    return {
        "context_frames": CONTEXT, "case_frames": SPAN, "case_step": CASE_STEP,
        "canonical_frame": "last context frame (window frame 9)",
        "style_clip_frames": STYLE_CLIP_FRAMES,
        "target": "the target frame alone" if target_frames == 1
                  else "the target frame and the frame before it (its velocity)",
        "noise": ("sampled, a seed per case and variant (as the API's default request)" if noise
                  else "none (deterministic)"),
        "style_pairing": "same style, another take of the split (120+ frames first, same content first), "
                         "hash-ranked; cross: a hash-chosen other style, same ranking",
    }


def describe_variants() -> list[dict[str, Any]]:
    """Every variant asked: its gap, frames, target changes and whether it has ground truth."""
    return [{"name": v.name, "label": v.label, "gap": v.gap, "frames": v.frames, "d": v.d, "dt": v.dt,
             "turn_deg": v.turn, "side_cm": v.side, "locomotion_only": v.locomotion_only,
             "ground_truth": v.has_ground_truth} for v in VARIANTS]


def describe_reference(stats: ReferenceStats, cases: CaseSet) -> dict[str, Any]:
    """The reference statistics: how many takes and windows, the feet and their ground heights."""
    return {"takes": stats.takes, "windows": stats.windows,
            "feet": [cases.skeleton.names[j] for j in stats.feet],
            "ground_cm": [round(x, 3) for x in stats.ground.tolist()]}


def describe_scorers(classifier: StyleClassifier | None, classifier_path: str | None,
                     judge: StyleJudge | None, judge_path: str | None,
                     judge2: SequenceJudge | None, judge2_path: str | None) -> dict[str, Any]:
    """The style classifier and the judges given (None for each one that is not)."""
    return {
        "classifier": None if classifier is None else {
            "path": classifier_path, "styles": classifier.styles, "inputs": classifier.config.inputs,
            "window": classifier.config.window},
        "judge": None if judge is None else {"path": judge_path, **judge.describe()},
        "judge2": None if judge2 is None else {"path": judge2_path, **judge2.describe()},
    }
